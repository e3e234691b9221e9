"""Drawing of an `episode_report.Episode` with matplotlib (Agg, no display; no rclpy).

One row per step: the camera frame with the detected tags outlined and labelled by id,
what was done (action, outcome, expected information gain), and the belief's top
candidates as horizontal bars (the true object, when the bag knows it, in green); a last
row with the result.
"""

import math
import textwrap

import matplotlib

matplotlib.use('Agg')

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

DEFAULT_DPI = 60
ROW_HEIGHT_IN = 2.1
WIDTH_IN = 10.0
TAG_COLOUR = '#00c853'
BAR_COLOUR = '#5c6bc0'
TRUTH_COLOUR = '#2e7d32'
TOP_ROWS = 5                   # bar slots per row (episode_report.TOP_CANDIDATES)


def _title(step):
    if not step.action:
        return 'start: the first view'
    text = f'{step.sequence}. {step.action}'
    text += f'  done in {step.duration_s:.1f} s' if step.success else '  FAILED'
    return text


def _details(step):
    lines = []
    if step.action and not math.isnan(step.expected_gain):
        lines.append(f'expected gain {round(step.expected_gain, 2) + 0.0:.2f} bits')
    if step.action and not step.success and step.reason:
        lines.append(f'why: {step.reason[:60]}')
    if step.belief_step >= 0:
        lines.append(f'belief step {step.belief_step}: H {step.entropy:.2f} bits')
    if step.detections_found:
        ids = sorted(t.tag_id for t in step.tags)
        lines.append('tags seen: ' + (', '.join(map(str, ids)) if ids else 'none'))
    else:
        lines.append('no tag detections recorded')
    return lines


def _draw_frame(ax, step, size):
    width, height = size
    if step.image is not None:
        image, scale = step.image, step.image_scale
        ax.imshow(image, cmap='gray' if image.ndim == 2 else None, vmin=0, vmax=255,
                  interpolation='nearest')
    else:
        scale = 320.0 / width
        ax.imshow(np.full((int(height * scale), int(width * scale)), 235, np.uint8),
                  cmap='gray', vmin=0, vmax=255)
        ax.text(0.5, 0.5, 'no image recorded', transform=ax.transAxes, ha='center',
                va='center', color='#757575', fontsize=9)
    for tag in step.tags:
        corners = tag.corners * scale
        ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor=TAG_COLOUR,
                             linewidth=1.5))
        ax.plot(*corners[0], 'o', color='#d50000', markersize=3)     # top-left corner
        cx, cy = corners.mean(axis=0)
        ax.text(cx, cy, str(tag.tag_id), ha='center', va='center', fontsize=9,
                fontweight='bold', color='black',
                bbox=dict(boxstyle='round,pad=0.15', facecolor='white', alpha=0.8,
                          edgecolor=TAG_COLOUR))
    ax.set_xticks([])
    ax.set_yticks([])


def _draw_bars(ax, candidates, truth):
    """Top candidates as bars; the probabilities are in the labels (one text each: text
    is what costs the time in Agg)."""
    ax.set_xlim(0.0, 1.0)
    ax.set_xticks([])
    ax.spines[['top', 'right', 'bottom']].set_visible(False)
    if not candidates:
        ax.set_yticks([])
        ax.spines['left'].set_visible(False)
        ax.text(0.5, 0.5, 'no belief recorded', ha='center', va='center', color='#757575')
        return
    labels = [f'{name} {p:5.3f}' for name, p in candidates][::-1]
    values = [p for _, p in candidates][::-1]
    colours = [TRUTH_COLOUR if truth and name == truth else BAR_COLOUR
               for name, _ in candidates][::-1]
    ax.barh(range(len(values)), values, color=colours, height=0.7)
    ax.set_ylim(-0.6, TOP_ROWS - 0.4)
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=8, family='monospace')
    ax.tick_params(axis='y', length=0)


def _result_text(episode):
    actions = episode.actions
    lines = ['result']
    if episode.final_candidates:
        name, p = episode.final_candidates[0]
        lines.append(f'most likely: {name}  P {p:.3f}')
        if episode.truth:
            lines.append(f'true object: {episode.truth}')
            lines.append('the most likely object is the true one' if name == episode.truth
                         else 'the most likely object is WRONG')
    failed = sum(not s.success for s in actions)
    lines.append(f'{len(actions)} actions' + (f' ({failed} failed)' if failed else '')
                 + f', {sum(s.duration_s for s in actions):.0f} s of action time')
    sequence = ' '.join(s.action for s in actions)
    lines += textwrap.wrap(sequence, 36)[:3]
    return lines


def draw_episode(episode, path, dpi=DEFAULT_DPI):
    """Write the episode's picture to `path` (PNG)."""
    rows = len(episode.steps) + 1
    fig = plt.figure(figsize=(WIDTH_IN, ROW_HEIGHT_IN * rows))
    # Columns: frame | words (figure text, no axes) on the left and the bars' labels on
    # the right | bars.
    grid = fig.add_gridspec(rows, 3, width_ratios=(2.8, 4.2, 2.6), hspace=0.25,
                            wspace=0.02, left=0.01, right=0.99, top=1 - 0.3 / rows,
                            bottom=0.05 / rows)
    fig.suptitle(f'episode report: {episode.bag}', fontsize=11, y=1 - 0.1 / rows)

    def words(row, title, lines, colour='black', mono=False):
        box = grid[row, 1].get_position(fig)
        fig.text(box.x0 + 0.005, box.y1, title, fontsize=11, fontweight='bold', va='top',
                 color=colour)
        fig.text(box.x0 + 0.005, box.y1 - 0.22 * box.height, '\n'.join(lines), fontsize=9,
                 va='top', linespacing=1.5, family='monospace' if mono else None)

    for row, step in enumerate(episode.steps):
        _draw_frame(fig.add_subplot(grid[row, 0]), step, episode.image_size)
        words(row, _title(step), _details(step),
              'black' if step.success else '#c62828')
        _draw_bars(fig.add_subplot(grid[row, 2]), step.candidates, episode.truth)
    lines = _result_text(episode)
    words(rows - 1, lines[0], lines[1:])
    _draw_bars(fig.add_subplot(grid[rows - 1, 2]), episode.final_candidates, episode.truth)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


__all__ = ['DEFAULT_DPI', 'draw_episode']
