"""What the perception benchmark and its realistic-conditions suite share (so that neither
imports the other's module): the random ARcube scene, the rotation error and the
Markdown section writer of ``--update-doc``.
"""

import os

import numpy as np


def random_scene(gen, models, rng, distance, n_distractors=2, effects=None):
    model = int(rng.integers(models.num_models))
    state = int(rng.integers(48))
    elevation = float(rng.uniform(25.0, 45.0))
    distractors = gen.random_distractors(n_distractors, models.n_tags, distance, elevation,
                                         in_range=1)
    return gen.render(models.faces[model], state, distance=distance, elevation_deg=elevation,
                      yaw_error_deg=float(rng.uniform(-8.0, 8.0)),
                      look_offset=rng.uniform(-0.4, 0.4, size=2), distractors=distractors,
                      effects=effects)


def rotation_deg(a, b):
    """Angle (deg) of the rotation between two rotation matrices."""
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))))


def update_doc(path, section, heading='Perception'):
    """Add or replace the '## <heading>' section of a Markdown file (others kept)."""
    import re
    text = open(path).read() if os.path.exists(path) else '# Benchmarks\n'
    pattern = re.compile(r'^## ' + re.escape(heading) + r'[ \t]*(\(.*\))?[ \t]*$.*?(?=^## |\Z)',
                         re.S | re.M)
    body = section.rstrip() + '\n\n'
    if pattern.search(text):
        text = pattern.sub(lambda _: body, text, count=1)
    else:
        text = text.rstrip() + '\n\n' + body
    with open(path, 'w') as stream:
        stream.write(text.rstrip() + '\n')
