"""Damped least-squares inverse kinematics for the hands (plain NumPy + Pinocchio, no rclpy).

The arms have 4 DOF each (shoulder pitch, shoulder roll, upper-arm yaw, elbow) and the
hands are balls, so targets are hand *positions* in `base_link`. One or both hands are
solved together, optionally with the torso pitch (shared by both arms: that is what
brings the hands down to a cube on the floor).

Each iteration takes a damped least-squares step (Levenberg-Marquardt damping that grows
with the error), adds a null-space pull towards a rest posture, and handles the joint
limits by clamping: joints that a step would push through a limit are frozen and the step
is solved again without them. Several seeds are tried; the result says why it failed.
"""

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from abp_description.kinematics import RobotKinematics


@dataclass
class IKResult:
    """Outcome of an IK solve: the full joint vector (13, /joint_states order)."""

    success: bool
    q: np.ndarray
    errors: dict = field(default_factory=dict)   # side -> residual distance, m
    iterations: int = 0
    reason: str = ''

    @property
    def error(self):
        return max(self.errors.values()) if self.errors else 0.0


class HandIK:
    """Position IK for one or both hands on a `RobotKinematics` model."""

    def __init__(self, kin=None, tol=1e-3, max_iter=200, damping=0.01, max_step=0.2,
                 limit_margin=0.01, posture_gain=0.05):
        self.kin = kin if kin is not None else RobotKinematics()
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.damping = float(damping)
        self.max_step = float(max_step)
        self.limit_margin = float(limit_margin)
        self.posture_gain = float(posture_gain)
        model = self.kin.model
        self.profile = self.kin.profile   # the arms, hand frames and torso joint
        self.sides = self.profile.sides
        self._fid = {s: model.getFrameId(f) for s, f in self.profile.hand_frames.items()}
        self._idx_v = np.array([model.joints[model.getJointId(n)].idx_v
                                for n in self.kin.joint_names])
        lo, hi = self.kin.lower_limits.copy(), self.kin.upper_limits.copy()
        finite = np.isfinite(lo) & np.isfinite(hi)
        margin = np.where(finite, np.minimum(self.limit_margin, 0.25 * (hi - lo)), 0.0)
        self._lo, self._hi = lo + margin, hi - margin

    def index(self, names):
        return np.array([self.kin.joint_index(n) for n in names], dtype=int)

    def hand_positions(self, q):
        """{side: (3,) hand position in base_link}."""
        pin.framesForwardKinematics(self.kin.model, self.kin.data, self.kin.to_pinocchio(q))
        return {s: self.kin.data.oMf[f].translation.copy() for s, f in self._fid.items()}

    def _fk_jac(self, q, sides):
        model, data = self.kin.model, self.kin.data
        q_pin = self.kin.to_pinocchio(q)
        pin.computeJointJacobians(model, data, q_pin)
        pin.updateFramePlacements(model, data)
        pos, jac = {}, {}
        for s in sides:
            fid = self._fid[s]
            pos[s] = data.oMf[fid].translation.copy()
            full = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            jac[s] = full[:3, self._idx_v]
        return pos, jac

    def active_joints(self, sides, use_torso=True):
        torso = self.profile.torso
        names = [torso.joint] if use_torso and torso is not None else []
        for s in sides:
            names.extend(self.profile.arms[s].joints)
        return tuple(names)

    def solve(self, targets, q_seed, use_torso=True, q_rest=None, seeds=(), tol=None):
        """Move the hands to `targets` ({side: xyz in base_link}).

        Joints other than the active ones (torso if `use_torso`, the arms of the sides in
        `targets`) keep their `q_seed` values. `q_rest` (default: the seed) is the posture
        the null-space term pulls towards; `seeds` are further starting postures (full
        joint vectors) tried when the first one fails. Returns an IKResult."""
        if not targets:
            raise ValueError('no IK targets')
        for side in targets:
            if side not in self.sides:
                raise ValueError(f'unknown hand {side!r}; expected one of {self.sides}')
        tol = self.tol if tol is None else float(tol)
        q_seed = np.asarray(q_seed, dtype=float)
        sides = tuple(s for s in self.sides if s in targets)
        target = {s: np.asarray(targets[s], dtype=float).reshape(3) for s in sides}
        active = self.index(self.active_joints(sides, use_torso))
        rest = q_seed if q_rest is None else np.asarray(q_rest, dtype=float)
        best = None
        total_iter = 0
        for start in (q_seed, *seeds):
            q0 = q_seed.copy()
            q0[active] = np.asarray(start, dtype=float)[active]
            result = self._solve_from(q0, target, sides, active, rest, tol)
            total_iter += result.iterations
            if best is None or result.error < best.error:
                best = result
            if result.success:
                break
        best.iterations = total_iter
        if not best.success:
            best.reason = self._failure_reason(best, active, tol)
        return best

    def _solve_from(self, q, target, sides, active, rest, tol):
        """Levenberg-Marquardt iterations: a step that does not reduce the error is
        rejected and the damping raised; an accepted one lowers it again."""
        q = q.copy()
        lo, hi = self._lo[active], self._hi[active]
        q[active] = np.clip(q[active], lo, hi)
        n = len(active)
        mu = 1.0   # Levenberg-Marquardt multiplier of the error-dependent damping
        pos, jac = self._fk_jac(q, sides)
        e = np.concatenate([target[s] - pos[s] for s in sides])
        it = 0
        best, since_best = np.inf, 0
        for it in range(1, self.max_iter + 1):
            errs = {s: float(np.linalg.norm(target[s] - pos[s])) for s in sides}
            if max(errs.values()) <= tol:
                return IKResult(True, q, errs, it)
            if max(errs.values()) < best - 1e-5:
                best, since_best = max(errs.values()), 0
            else:
                since_best += 1
                if since_best > 30:
                    break  # converged onto the closest reachable point
            J = np.vstack([jac[s][:, active] for s in sides])
            lam2 = mu * (self.damping ** 2 + 0.1 * float(e @ e))
            posture = self.posture_gain * (rest[active] - q[active])
            free = np.ones(n, dtype=bool)
            dq = np.zeros(n)
            for _ in range(n):
                Jf = J * free
                A = Jf @ Jf.T + lam2 * np.eye(len(e))
                dq = Jf.T @ np.linalg.solve(A, e)
                # Exact projector on the null space (a damped one would leak the posture
                # pull into the task).
                null = np.eye(n) - np.linalg.pinv(Jf, rcond=1e-4) @ Jf
                dq = dq + (null @ (posture * free)) * free
                qn = q[active] + dq
                push_out = ((qn < lo) & (dq < 0)) | ((qn > hi) & (dq > 0))
                push_out &= free
                if not push_out.any():
                    break
                free &= ~push_out
            step = np.max(np.abs(dq))
            if step > self.max_step:
                dq *= self.max_step / step
            q_new = q.copy()
            q_new[active] = np.clip(q[active] + dq, lo, hi)
            pos_new, jac_new = self._fk_jac(q_new, sides)
            e_new = np.concatenate([target[s] - pos_new[s] for s in sides])
            if e_new @ e_new < e @ e - 1e-12:
                q, pos, jac, e = q_new, pos_new, jac_new, e_new
                mu = max(mu / 2.0, 1.0)
            else:
                mu *= 4.0
                if mu > 1e4:
                    break  # no step reduces the error: a minimum of the residual
        errs = {s: float(np.linalg.norm(target[s] - pos[s])) for s in sides}
        return IKResult(max(errs.values()) <= tol, q, errs, it)

    def _failure_reason(self, result, active, tol):
        worst = max(result.errors, key=result.errors.get)
        at_limit = [self.kin.joint_names[i] for i in active
                    if result.q[i] <= self._lo[i] + 5e-3 or result.q[i] >= self._hi[i] - 5e-3]
        reason = (f'{worst} hand target out of reach (residual '
                  f'{1000 * result.errors[worst]:.1f} mm > {1000 * tol:.1f} mm)')
        if at_limit:
            reason += f' ({", ".join(at_limit)} at limit)'
        return reason

