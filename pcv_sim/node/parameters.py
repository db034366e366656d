"""A node's parameters: each declared from its one declaration (dynamic typing, so that a wrong type
gets our message, not rcl's); a `-p` override rcl dropped for its type is applied and checked like
any value; names nobody declares are refused (or, with allow_unknown_parameters, warned about), at
start and at run time ("unknown parameter(s) x (did you mean y?)", not rclpy's "undeclared
parameter(s): []"); a numeric text for a float parameter (`ros2 param set` sends 2e-5 as text) is
the number; use_sim_time cannot change while the node runs, nor go with simulated time.

A change at run time is checked on the worker thread with the rules at start (`_validate_parameters`),
what it needs prepared there (`_prepare`), and applied by the loop between wakes (`_put_in_force`:
`pcv_sim.node.services` answers the request only then): `check_change` and `queue_change`, the
shape every node's run-time change has (the steering controller's gains too).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from pcv_sim.device.device import Device
from pcv_sim.device.parameters import (
    Override,
    is_ros_own,
    numeric_text,
    override_not_taken,
    refuse_unknown,
    unknown_parameters_message,
)
from pcv_sim.device.settings import SettingsSchema
from pcv_sim.errors import ParameterError
from pcv_sim.simulation.clock import SIM_TIME_CONFLICT

__all__ = ["NodeParameters", "ros_value"]


def ros_value(value: Any) -> Any:
    """A checked value as a ROS parameter value (ints given for a float parameter stay numbers)."""
    return list(value) if isinstance(value, tuple) else value


class NodeParameters(Node):
    """The parameter part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    #: What the unknown-name message adds (where the other parameters are set).
    unknown_hint = ""
    #: The node's settings (`pcv_sim.device.settings.SettingsSchema`): what it declares and how it checks.
    schema: SettingsSchema[Any]
    settings: Any
    device: Device
    external_clock: bool            # use_sim_time: the model follows an external /clock
    _cli: dict[str, Override]       # the command line's -p overrides
    _deferred_callbacks: tuple[Any, ...]                        # pcv_sim.node.services
    _ready: list[Callable[[], None]]
    _retime: Callable[[Any], None]                              # pcv_sim.node.loops

    def _init_parameters(self) -> None:
        self._retaken: dict[str, Override] = {}      # -p overrides rcl dropped, applied by us
        self._declared: set[str] = set()
        self._float_names: set[str] = set()
        self._pending: tuple[Any, Any] | None = None                # (settings, device parameters) of the running job
        self._staged: Any = None                                    # checked, about to be queued for the loop
        self._deferred_callbacks += (self._on_set_parameters, self._on_set_parameters_atomically)

    def declare(self, name: str, default: Any, description: str, *, read_only: bool = False,
                is_float: bool = False) -> Any:
        """Declare one parameter; its value as given (the command line's if rcl dropped it)."""
        desc = ParameterDescriptor(description=description, dynamic_typing=True, read_only=read_only)
        value = self.declare_parameter(name, default, desc).value
        self._declared.add(name)
        if is_float:
            self._float_names.add(name)
        override = self._cli.get(name)
        if override is None or not override_not_taken(override, value):
            return value
        self._retaken[name] = override
        return override.value

    def declare_node_parameters(self) -> tuple[Any, Any]:
        """Declare the node's settings (`schema`) and the device's parameters (`_device_parameters`);
        the settings and the device's parameters, cross-checked. Refused (ParameterError naming it):
        an invalid value, and beyond what rcl checks, a params file with a key given twice, a `-p`
        override that did not take (rcl drops one whose type differs from the params file's), names
        nobody declares (unless allow_unknown_parameters; see pcv_sim.device.parameters)."""
        settings = self.schema.settings_from(self.declare_settings(self.schema.parameters, self.schema.check))
        self.take_parameter_services(bool(self.get_parameter("use_sim_time").value), settings.time_mode == "simulated")
        params = self._device_parameters(settings)
        self.refuse_unknown_names(settings.allow_unknown_parameters)
        self.set_retaken()
        settings.check(params)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        return settings, params

    def _device_parameters(self, settings: Any) -> Any:
        """The device's parameters (its YAML), with those the node declares for it applied."""
        raise NotImplementedError

    def _validate_parameters(self, parameters: list[Any]) -> SetParametersResult:
        """on-set callback (worker thread): the whole change checked with the rules at start and staged
        (`_checked_change`); the loop applies it (`_pump`). use_sim_time cannot change; rclpy refuses
        the read-only ones."""
        refused = self.sim_time_change_refused(parameters)
        if refused is not None:
            return refused
        return self.check_change(parameters, self._checked_change)

    def _checked_change(self, parameters: list[Any]) -> tuple[Any, Any, Any]:
        """The settings (by the schema) and the device's parameters (by `_prepare`) with the change,
        cross-checked, and what the device needs prepared for them; a change the model cannot run
        with is refused saying so. The base holds the changes queued before and not yet applied."""
        settings_changes = {p.name: p.value for p in parameters if p.name in self.schema.by_name}
        device_changes = {p.name: p.value for p in parameters
                          if p.name not in self.schema.by_name and p.name in self._declared}
        base_settings, base_params = self._pending or (self.settings, self.device_params)
        try:
            settings = self.schema.with_changes(base_settings, settings_changes)
            params, prepared = self._prepare(base_params, device_changes)
            settings.check(params)
        except ValueError:                  # ParameterError among them: its own words
            raise
        except Exception as err:
            raise ParameterError(f"the model cannot run with these parameters: {type(err).__name__}: {err}") from err
        return settings, params, prepared

    @property
    def device_params(self) -> Any:
        """The device's parameters in force."""
        return self.device.params

    def _prepare(self, params: Any, changes: dict[str, Any]) -> tuple[Any, Any]:
        """Worker thread: `params` with the device's parameter `changes`, and what the loop installs for
        them (None: nothing); ParameterError for a refused change."""
        return params, None

    def _apply_parameters(self, parameters: list[Any]) -> None:
        """post-set callback (worker thread): what `_validate_parameters` staged, queued for the loop;
        the base of the next change until the loop has applied it."""
        staged = self.queue_change(parameters, self._put_in_force)
        if staged is not None:
            self._pending = staged[:2]

    def _put_in_force(self, staged: tuple[Any, Any, Any]) -> Callable[[], None] | None:
        """On the loop, between wakes: the new settings in force from the next step; what the device
        prepared is installed after the "parameters changed" line (`_install` logs its own)."""
        settings, _, prepared = staged
        self.settings = settings
        self._apply_settings(settings)
        self._retime(settings)
        return None if prepared is None else lambda: self._install(prepared)

    # --- a change at run time: checked on the service worker, put in force by the loop --------------

    def check_change(self, parameters: list[Any], check: Callable[[list[Any]], Any]) -> SetParametersResult:
        """An on-set callback's body (the service worker): `check(parameters)` checks the change with
        the rules at start; what it returns is staged for `queue_change` (None: nothing to put in
        force), what it raises (ParameterError, ValueError) refuses the request with its text."""
        try:
            staged = check(parameters)
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        if staged is not None:
            self._staged = staged
        return SetParametersResult(successful=True)

    def queue_change(self, parameters: list[Any], put_in_force: Callable[[Any], Callable[[], None] | None]) -> Any:
        """A post-set callback's body (the service worker): what `check_change` staged, queued for the
        loop, which between two periods puts it in force (`put_in_force(staged)`), logs "parameters
        changed: <name> = <value>, ..." and then runs what `put_in_force` returned, if anything (a
        step that logs its own line after). The staged value, or None when nothing was staged."""
        staged, self._staged = self._staged, None
        if staged is None:
            return None
        changed = ", ".join(f"{p.name} = {p.value!r}" for p in parameters)

        def apply() -> None:
            then = put_in_force(staged)
            self.get_logger().info(f"parameters changed: {changed}")
            if then is not None:
                then()

        self._ready.append(apply)
        return staged

    def _apply_settings(self, settings: Any) -> None:
        """The settings the device holds (watchdog, safe duty...) into it (none here)."""

    def _install(self, prepared: Any) -> None:
        """What `_prepare` made, into the device (on the loop)."""
        raise NotImplementedError

    def declare_settings(self, specs: Iterable[Any], check: Callable[[str, Any], Any]) -> dict[str, Any]:
        """Declare each setting from its one declaration (`pcv_sim.params.setting`), described by its
        doc, the range it accepts and its unit; its value checked by `check(name, value)` as soon as
        it is declared (ParameterError naming it)."""
        return {spec.name: check(spec.name, self.declare(spec.name, spec.default, f"{spec.described} [{spec.unit}]",
                                                          read_only=spec.read_only, is_float=spec.is_float))
                for spec in specs}

    def refuse_unknown_names(self, allowed: bool) -> None:
        """Names given (params file, -p) that nobody declared: ParameterError, or a warning if allowed."""
        overrides = set(getattr(self, "_parameter_overrides", {}) or {}) | set(self._cli)
        unknown = sorted(n for n in overrides if n not in self._declared and not is_ros_own(n))
        if unknown and not allowed:
            refuse_unknown(unknown, self._declared, hint=self.unknown_hint)
        if unknown:
            self.get_logger().warning(f"ignoring unknown parameter(s) (allow_unknown_parameters): {', '.join(unknown)}")

    def set_retaken(self) -> None:
        """After declaring: the values rcl dropped (and we took) set on the node, so that they read back."""
        if self._retaken:
            self.set_parameters([Parameter(n, value=ros_value(o.value)) for n, o in self._retaken.items()])

    def take_parameter_services(self, external_clock: bool, simulated: bool) -> None:
        """The parameter services answered by ours (unknown names named, numeric text for floats);
        use_sim_time with simulated time refused (ParameterError)."""
        if external_clock and simulated:
            raise ParameterError(SIM_TIME_CONFLICT)
        self.external_clock = external_clock
        for srv in self.services:
            if srv.srv_name.endswith("/set_parameters"):
                srv.callback = self._on_set_parameters
            elif srv.srv_name.endswith("/set_parameters_atomically"):
                srv.callback = self._on_set_parameters_atomically

    def _set_checked(self, parameters: list[Any]) -> SetParametersResult:   # rclpy Parameters (generic from kilted on)
        parameters = [Parameter(p.name, value=numeric_text(p.value)) if p.name in self._float_names else p
                      for p in parameters]
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            return SetParametersResult(successful=False, reason=unknown_parameters_message(
                unknown, self._declared, hint=self.unknown_hint.split("; allow_unknown", maxsplit=1)[0]))
        return self.set_parameters_atomically(parameters)

    def _on_set_parameters(self, request: Any, response: Any) -> Any:
        """SetParameters service: one result per parameter, each set on its own (as rclpy does)."""
        for msg in request.parameters:
            response.results.append(self._set_checked([Parameter.from_parameter_msg(msg)]))
        return response

    def _on_set_parameters_atomically(self, request: Any, response: Any) -> Any:
        response.result = self._set_checked([Parameter.from_parameter_msg(m) for m in request.parameters])
        return response

    def sim_time_change_refused(self, parameters: Iterable[Any]) -> SetParametersResult | None:
        """use_sim_time (ROS's own, not read-only) cannot change while the node runs: the reason, or None."""
        for p in parameters:
            if p.name == "use_sim_time" and bool(p.value) != self.external_clock:
                return SetParametersResult(successful=False, reason=(
                    "use_sim_time is fixed while the node runs (the model's clock is chosen at start): restart "
                    f"with -p use_sim_time:={'true' if p.value else 'false'}"))
        return None
