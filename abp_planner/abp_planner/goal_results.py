"""The Recognize result of a finished episode (abp_msgs messages, no rclpy): the one-object
episode's (`episode.EpisodeRunner`) and a task's (`scene_episode.SceneEpisodeRunner`), and
how the goal ends. The planner node stamps `elapsed` and ends the goal handle."""

from abp_msgs.action import Recognize
from abp_msgs.msg import Belief, ObjectResult

from .episode import ABORTED, CANCELED

# Candidates a Recognize result lists.
TOP_CANDIDATES = 5
SUCCEED, ABORT, CANCEL = 'succeed', 'abort', 'canceled'


def goal_end(episode):
    """How the goal handle ends: an episode that did not identify (budget spent, a node
    lost) is aborted, never reported as a success."""
    if episode.outcome == CANCELED:
        return CANCEL
    if episode.outcome == ABORTED or not episode.success:
        return ABORT
    return SUCCEED


def _fill_top(result, belief):
    if belief.object_ids:
        result.object_id = belief.object_ids[0]
        result.posterior = float(belief.probabilities[0])
        result.top_object_ids = list(belief.object_ids[:TOP_CANDIDATES])
        result.top_posteriors = [float(p) for p in belief.probabilities[:TOP_CANDIDATES]]


def single_result(episode):
    """The result of a one-object episode: its final belief's candidates."""
    result = Recognize.Result(actions_taken=episode.actions_taken, success=episode.success,
                              reason=episode.reason)
    _fill_top(result, episode.belief or Belief())
    return result


def scene_result(episode, model_names, goal):
    """The result of a task's episode: one ObjectResult per track; the one-object fields
    name the object the task was about (identify's track, find's found track, or the
    only object of the scene)."""
    result = Recognize.Result(actions_taken=episode.actions_taken, success=episode.success,
                              reason=episode.reason, found_track_id=episode.found_object)
    result.objects = [ObjectResult(track_id=str(o.object_id), object_id=model_names[o.model],
                                   posterior=float(o.posterior), actions_taken=o.actions,
                                   decided=bool(o.identified), reason=o.reason)
                      for o in episode.objects]
    view = episode.view
    if goal.task == Recognize.Goal.TASK_IDENTIFY:
        track = goal.track_id
    else:
        track = view.object_ids[0] if view is not None and len(view) == 1 else ''
    focus = episode.found_object or track
    if view is not None and focus in view:
        _fill_top(result, view.message(focus))
    return result


__all__ = ['TOP_CANDIDATES', 'goal_end', 'scene_result', 'single_result']
