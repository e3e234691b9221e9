"""The sim bridge's parameter table and its run-time change rule (no ROS)."""

import pytest

from abp_belief.model_set_config import POPULATION_SPECS
from abp_common.param_spec import ParamSpec
from abp_sim_bridge import config as cfg


def test_the_table_is_param_specs_sharing_the_model_set_parameters():
    assert all(isinstance(p, ParamSpec) for p in cfg.PARAMETERS)
    assert len(set(cfg.PARAMETER_NAMES)) == len(cfg.PARAMETERS)
    by_name = {p.name: p for p in cfg.PARAMETERS}
    for spec in POPULATION_SPECS:  # same name, kind, default, range and meaning
        mine = by_name[spec.name]
        assert (mine.kind, mine.default, mine.range, mine.description, mine.choices) == \
            (spec.kind, spec.default, spec.range, spec.description, spec.choices)
        assert not mine.read_only  # the world is rebuilt with them at ~/reset_world


def test_notes_say_when_a_change_takes_effect():
    by_name = {p.name: p for p in cfg.PARAMETERS}
    assert cfg.description_note(by_name['speedup']) == ''
    assert 'start only' in cfg.description_note(by_name['publish_clock'])
    assert 'reset_world' in cfg.description_note(by_name['mass_index'])


def test_changes_are_refused_with_a_reason_naming_the_parameter():
    values = cfg.defaults()
    assert cfg.refusal(values, {'speedup': 10.0}) == ''
    assert cfg.refusal(values, {'use_sim_time': True}) == ''  # not ours: ignored
    assert cfg.refusal(values, {'mass_index': 3, 'cube_seed': 4}) == ''
    assert 'publish_clock' in cfg.refusal(values, {'publish_clock': False})
    assert 'camera_encoding' in cfg.refusal(values, {'camera_encoding': 'rgb8'})
    assert 'camera_rate' in cfg.refusal(values, {'camera_rate': 80.0})
    # Checked together with the current values: camera_rate may not exceed rate.
    assert 'camera_rate' in cfg.refusal({**values, 'camera_rate': 20.0}, {'rate': 15.0})


def test_the_tag_dictionary_must_exist_and_hold_every_tag_drawn():
    assert cfg.build({'dictionary': 'DICT_APRILTAG_36h11'}).camera.dictionary == \
        'DICT_APRILTAG_36h11'
    with pytest.raises(ValueError, match='dictionary: unknown ArUco dictionary'):
        cfg.build({'dictionary': 'DICT_NOT_A_FAMILY'})
    # AprilTag 16h5 has 30 ids: a cube with tag 40 cannot be drawn in it.
    with pytest.raises(ValueError, match='DICT_APRILTAG_16h5 has 30 tag ids.*up to 40'):
        cfg.build({'dictionary': 'DICT_APRILTAG_16h5', 'face_tags': [0, 1, 2, 3, 4, 40]})
