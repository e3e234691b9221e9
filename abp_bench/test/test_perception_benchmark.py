"""The perception benchmark runs end to end (tiny sizes) and edits only its own section."""

from abp_bench import perception_benchmark


def test_benchmark_runs_and_prints_the_tables(capsys):
    assert perception_benchmark.main(['--frames', '2', '--noise-frames', '0',
                                      '--match-trials', '4', '--distance-trials', '0',
                                      '--robot-trials', '3', '--rigid-frames', '2']) == 0
    out = capsys.readouterr().out
    assert out.startswith('## Perception')
    for heading in ('### Goals', '### Detection by distance', '### Aspect matching',
                    '### Rigid-cube pose'):
        assert heading in out
    assert '| face-centre error at 1 m (median) | ≤ 5 mm |' in out


def test_update_doc_replaces_only_the_perception_section(tmp_path):
    doc = tmp_path / 'BENCHMARKS.md'
    doc.write_text('# Benchmarks\n\n## Belief\n\nbelief table\n\n## Perception\n\nold\n\n'
                   '## Planner\n\nplanner table\n')
    perception_benchmark.update_doc(doc, '## Perception\n\nnew tables\n')
    text = doc.read_text()
    assert 'new tables' in text and 'old' not in text
    assert text.index('## Belief') < text.index('## Perception') < text.index('## Planner')
    assert 'belief table' in text and 'planner table' in text
    fresh = tmp_path / 'NEW.md'
    perception_benchmark.update_doc(fresh, '## Perception\n\nx\n')
    assert fresh.read_text() == '# Benchmarks\n\n## Perception\n\nx\n'
