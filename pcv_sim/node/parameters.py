"""A node's parameters: each declared from its one declaration (dynamic typing, so that a wrong type
gets our message, not rcl's); a `-p` override rcl dropped for its type is applied and checked like
any value; names nobody declares are refused (or, with allow_unknown_parameters, warned about), at
start and at run time ("unknown parameter(s) x (did you mean y?)", not rclpy's "undeclared
parameter(s): []"); a numeric text for a float parameter (`ros2 param set` sends 2e-5 as text) is
the number; use_sim_time cannot change while the node runs, nor go with simulated time.

A change at run time is checked on the worker thread with the rules at start (`_validate_parameters`),
what it needs prepared there (`_prepare`), and applied by the loop between wakes (`_apply`:
`pcv_sim.node.services` answers the request only then).
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
        self._staged: tuple[Any, Any, Any] | None = None            # checked, about to be queued for the loop
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
        """on-set callback (worker thread): the whole change checked with the rules at start (settings
        by the schema, the device's parameters by `_prepare`), what it needs prepared and staged; the
        loop applies it (`_pump`). use_sim_time cannot change; rclpy refuses the read-only ones."""
        refused = self.sim_time_change_refused(parameters)
        if refused is not None:
            return refused
        settings_changes = {p.name: p.value for p in parameters if p.name in self.schema.by_name}
        device_changes = {p.name: p.value for p in parameters
                          if p.name not in self.schema.by_name and p.name in self._declared}
        base_settings, base_params = self._pending or (self.settings, self.device_params)
        try:
            settings = self.schema.with_changes(base_settings, settings_changes)
            params, prepared = self._prepare(base_params, device_changes)
            settings.check(params)
        except (ParameterError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        except Exception as err:
            return SetParametersResult(successful=False,
                                       reason=f"the model cannot run with these parameters: {type(err).__name__}: {err}")
        self._staged = (settings, params, prepared)
        return SetParametersResult(successful=True)

    @property
    def device_params(self) -> Any:
        """The device's parameters in force."""
        return self.device.params

    def _prepare(self, params: Any, changes: dict[str, Any]) -> tuple[Any, Any]:
        """Worker thread: `params` with the device's parameter `changes`, and what the loop installs for
        them (None: nothing); ParameterError for a refused change."""
        return params, None

    def _apply_parameters(self, parameters: list[Any]) -> None:
        """post-set callback (worker thread): queue what `_validate_parameters` staged for the loop."""
        if self._staged is None:
            return
        settings, params, prepared = self._staged
        self._staged = None
        self._pending = (settings, params)
        changed = ", ".join(f"{p.name} = {p.value!r}" for p in parameters)
        self._ready.append(lambda: self._apply(settings, prepared, changed))

    def _apply(self, settings: Any, prepared: Any, changed: str) -> None:
        """On the loop, between wakes: the new settings (and what the device prepared) in force from the
        next step."""
        self.settings = settings
        self._apply_settings(settings)
        self._retime(settings)
        self.get_logger().info(f"parameters changed: {changed}")
        if prepared is not None:
            self._install(prepared)

    def _apply_settings(self, settings: Any) -> None:
        """The settings the device holds (watchdog, safe duty...) into it (none here)."""

    def _install(self, prepared: Any) -> None:
        """What `_prepare` made, into the device (on the loop)."""
        raise NotImplementedError

    def declare_settings(self, specs: Iterable[Any], check: Callable[[str, Any], Any]) -> dict[str, Any]:
        """Declare each setting from its one declaration (`pcv_sim.params.setting`); its value checked
        by `check(name, value)` as soon as it is declared (ParameterError naming it)."""
        return {spec.name: check(spec.name, self.declare(spec.name, spec.default, f"{spec.description} [{spec.unit}]",
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
