"""What a managed node made in each lifecycle transition, kept by the node itself, so
that the way back (deactivate, cleanup) destroys exactly that, with rclpy's public API.

`EntityRegistry` is a mixin for an rclpy Node class. Its factory methods are rclpy's
(`create_publisher`, `create_subscription`, `create_service`, `create_client`,
`create_timer` (and so `create_rate`), `create_guard_condition`,
`create_lifecycle_publisher`, `add_waitable` (action servers and clients register
themselves through it), the three `add_*_set_parameters_callback`, `declare_parameters`
(and so `declare_parameter`)); while `recording(phase)` is open, each also notes what it
made and how to undo it. `undo(phase)` undoes a phase's notes, newest first, with the
public counterparts: `destroy_*`, the action object's own `destroy()` (or
`remove_waitable`), `remove_*_set_parameters_callback`, `undeclare_parameter`. What the
node makes outside a recording (rclpy's lifecycle and parameter services, the
`~/endpoint_status` service, the health publisher built in a constructor) is never noted,
so it survives every transition. The registry also holds the only reference to an action
server a node builds without keeping one.

A read-only parameter cannot be undeclared (rclpy refuses it), and its value cannot change
either: it stays declared through a cleanup, and declaring it again in the next configure
returns it as it is (the value given at start, as a fresh declaration would).
"""

from contextlib import contextmanager


class EntityRegistry:
    """Mixin for an rclpy Node class: see the module docstring."""

    # -- the recording -------------------------------------------------------------------
    def registry_init(self):
        """Call before rclpy's Node constructor (which already calls the factories)."""
        self._made_in = {}            # phase -> [(undo, entity)], oldest first
        self._recording_into = None   # the list the factories add to, while one is open
        self._kept_read_only = set()  # read-only parameters a cleanup left declared

    @contextmanager
    def recording(self, phase):
        """Note everything the factories make inside the block as made by `phase`
        (added to what the phase made before)."""
        self._recording_into = self._made_in.setdefault(phase, [])
        try:
            yield
        finally:
            self._recording_into = None

    def made_in(self, phase):
        """What `phase` made and has not undone yet: [entity], oldest first."""
        return [entity for _, entity in self._made_in.get(phase, [])]

    def undo(self, phase, on_error):
        """Undo what `phase` made, newest first; `on_error(entity, exception)` reports a
        failure, and the rest is still undone."""
        made = self._made_in.pop(phase, [])
        for undo, entity in reversed(made):
            try:
                undo(entity)
            except Exception as error:  # noqa: BLE001 -- reported; the rest still goes
                on_error(entity, error)

    def _note(self, undo, entity):
        if getattr(self, '_recording_into', None) is not None:
            self._recording_into.append((undo, entity))
        return entity

    # -- factories -----------------------------------------------------------------------
    def create_publisher(self, *args, **kwargs):
        return self._note(self.destroy_publisher, super().create_publisher(*args, **kwargs))

    def create_lifecycle_publisher(self, *args, **kwargs):
        return self._note(self.destroy_lifecycle_publisher,
                          super().create_lifecycle_publisher(*args, **kwargs))

    def create_subscription(self, *args, **kwargs):
        return self._note(self.destroy_subscription,
                          super().create_subscription(*args, **kwargs))

    def create_service(self, *args, **kwargs):
        return self._note(self.destroy_service, super().create_service(*args, **kwargs))

    def create_client(self, *args, **kwargs):
        return self._note(self.destroy_client, super().create_client(*args, **kwargs))

    def create_timer(self, *args, **kwargs):
        return self._note(self.destroy_timer, super().create_timer(*args, **kwargs))

    def create_guard_condition(self, *args, **kwargs):
        return self._note(self.destroy_guard_condition,
                          super().create_guard_condition(*args, **kwargs))

    def add_waitable(self, waitable):
        super().add_waitable(waitable)
        self._note(self._destroy_waitable, waitable)

    def add_pre_set_parameters_callback(self, callback):
        super().add_pre_set_parameters_callback(callback)
        self._note(self._remove_callback(self.remove_pre_set_parameters_callback), callback)

    def add_on_set_parameters_callback(self, callback):
        result = super().add_on_set_parameters_callback(callback)
        self._note(self._remove_callback(self.remove_on_set_parameters_callback), callback)
        return result

    def add_post_set_parameters_callback(self, callback):
        super().add_post_set_parameters_callback(callback)
        self._note(self._remove_callback(self.remove_post_set_parameters_callback), callback)

    def declare_parameters(self, namespace, parameters, ignore_override=False):
        def full_name(parameter):
            return f'{namespace}.{parameter[0]}' if namespace else parameter[0]

        kept = [full_name(p) in self._kept_read_only for p in parameters]
        fresh = [p for p, is_kept in zip(parameters, kept) if not is_kept]
        try:
            declared = iter(super().declare_parameters(namespace, fresh, ignore_override))
        except Exception:
            # rclpy declares one at a time: those before the refused one stay declared.
            for parameter in fresh:
                if self.has_parameter(full_name(parameter)):
                    self._note(self._undeclare, full_name(parameter))
            raise
        result = []
        for parameter, is_kept in zip(parameters, kept):
            if is_kept:
                self._kept_read_only.discard(full_name(parameter))
                result.append(self.get_parameter(full_name(parameter)))
            else:
                result.append(next(declared))
            self._note(self._undeclare, result[-1].name)
        return result

    # -- undoing -------------------------------------------------------------------------
    def _destroy_waitable(self, waitable):
        # Destroying a publisher or subscription already removed its QoS event handlers.
        if not any(w is waitable for w in self.waitables):
            return
        destroy = getattr(waitable, 'destroy', None)
        if destroy is not None:
            destroy()            # an action server or client removes itself from the node
        if any(w is waitable for w in self.waitables):
            self.remove_waitable(waitable)

    @staticmethod
    def _remove_callback(remove):
        def remove_if_present(callback):
            try:
                remove(callback)
            except ValueError:   # already removed by the node itself
                pass
        return remove_if_present

    def _undeclare(self, name):
        if not self.has_parameter(name):
            return
        if self.describe_parameter(name).read_only:
            self._kept_read_only.add(name)
        else:
            self.undeclare_parameter(name)


__all__ = ['EntityRegistry']
