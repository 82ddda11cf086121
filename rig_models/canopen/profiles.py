"""Device profiles on a VirtualNode: CiA 402 drive, CiA 401 I/O module, CiA 406 encoder.

Raw CANopen values in and out, no physics: the virtual rig's glue (``rig_devices``) calls these each
physics step and maps raw values to SI with the rig file (per mille of 0x6076 rated torque,
0.001 rad/s velocity counts, 10/32768 V analog counts, 1e-7 rad encoder counts: the EDS files
and docs/canopen.md say which).
"""

from __future__ import annotations

from enum import Enum

from rig_models.canopen.node import (
    ABORT_VALUE_RANGE,
    EMCY_HEARTBEAT,
    EMCY_RESET,
    ERR_GENERIC,
    ERR_PROFILE,
    NmtState,
    VirtualNode,
    error_register_bits,
)

MODE_PV = 3
MODE_CSV = 9
MODE_CST = 10
_MODE_NAMES = {"pv": MODE_PV, "csv": MODE_CSV, "cst": MODE_CST}
# 0x6502 bit of each mode (CiA 402 6.2.4)
_MODE_BITS = {MODE_PV: 1 << 2, MODE_CSV: 1 << 8, MODE_CST: 1 << 9}
# the modes that follow the target velocity 0x60FF (profile velocity ramps to it by the
# drive's own profile acceleration; the rig's physics has its own speed lag instead)
_VELOCITY_MODES = (MODE_PV, MODE_CSV)


class DriveState(Enum):
    """CiA 402 power drive system states, with their statusword bits (bits 0-3, 5, 6)."""

    NOT_READY_TO_SWITCH_ON = 0x00
    SWITCH_ON_DISABLED = 0x40
    READY_TO_SWITCH_ON = 0x21
    SWITCHED_ON = 0x23
    OPERATION_ENABLED = 0x27
    QUICK_STOP_ACTIVE = 0x07
    FAULT_REACTION_ACTIVE = 0x0F
    FAULT = 0x08


# the power stage is on: what an abort connection (0x6007) has to act on
_POWERED = (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCHED_ON,
            DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE)
_VOLTAGE_ENABLED = 0x10
_REMOTE = 0x200
_FOLLOWS_COMMAND = 0x1000  # CSV/CST: the drive follows the command value


def _require(node: VirtualNode, objects: list[tuple[int, int]], profile: str) -> None:
    missing = [f"0x{i:04X}:{s:02X}" for i, s in objects if not node.has(i, s)]
    if missing:
        raise ValueError(f"{node.eds_path.name}: not a {profile} device, it lacks "
                         + ", ".join(missing))


# the profile objects the profiles compute with: an integer type each, or no emulation
_PROFILE_OBJECTS = (0x6000, 0x6004, 0x6007, 0x6030, 0x603F, 0x6040, 0x6041, 0x6060, 0x6061,
                    0x606C, 0x6071, 0x6072, 0x6077, 0x60FF, 0x6200, 0x6206, 0x6207, 0x6401,
                    0x6411, 0x6443, 0x6444, 0x6502)


def _integers(node: VirtualNode, profile: str) -> None:
    for (index, sub), value in node.values.items():
        if index in _PROFILE_OBJECTS and (isinstance(value, bool | float | str | bytes)):
            var = node.variable(index, sub)
            raise ValueError(f"{node.eds_path.name}: 0x{index:04X}:{sub:02X} ({var.name}) has "
                             f"data type 0x{var.data_type or 0:X}, {profile} makes it an "
                             "integer")


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


class Cia402Drive:
    """CiA 402 drive in cyclic synchronous torque ('cst', 10), cyclic synchronous velocity
    ('csv', 9) or profile velocity ('pv', 3) mode.

    The controlword state machine runs on every master write of 0x6040 (SDO or RPDO). A
    fault passes through 'fault reaction active' (drive already torque-free) to 'fault' at
    the next SYNC. The abort connection option 0x6007 (0 none, 1 fault, 2 disable voltage,
    3 quick stop) is applied, while the power stage is on, on a heartbeat consumer timeout,
    on NMT stopped and on a reset communication (a reset node resets the drive anyway).
    """

    def __init__(self, node: VirtualNode, mode: str | int) -> None:
        # what the emulation cannot do without: the state machine's two words and the
        # mode's target object. Everything else CiA 402 makes optional, and a drive without
        # it behaves as such a drive does: no 0x6060/0x6061, it runs its one mode; no
        # 0x6502, it takes the mode it is told; no 0x603F, the fault is in the status word
        # and the EMCY only; no 0x6007, CiA 402's default reaction (1: fault); no 0x6072,
        # no torque limit beyond the target's own range
        _require(node, [(0x6040, 0), (0x6041, 0)], "CiA 402")
        _integers(node, "CiA 402")
        if isinstance(mode, str):
            if mode.lower() not in _MODE_NAMES:
                raise ValueError(f"mode: {mode!r} is not 'cst', 'csv' or 'pv'")
            mode = _MODE_NAMES[mode.lower()]
        if mode not in _MODE_BITS:
            raise ValueError(f"mode: {mode}: the virtual drive emulates profile velocity "
                             f"({MODE_PV}), cyclic synchronous velocity ({MODE_CSV}) and "
                             f"torque ({MODE_CST}) only")
        supported = node.get(0x6502) if node.has(0x6502) else None
        if supported is not None and not supported & _MODE_BITS[mode]:
            raise ValueError(f"mode: {mode} is not supported by {node.eds_path.name} "
                             f"(0x6502 = 0x{supported:X})")
        _require(node, [(0x6071, 0)] if mode == MODE_CST else [(0x60FF, 0)],
                 f"CiA 402 mode {mode}")
        self.node = node
        self.mode = mode
        self._has_mode = node.has(0x6060) and node.has(0x6061)
        self._has_error_code = node.has(0x603F)
        self._last_cw = 0
        self._reset()
        node.add_write_listener(0x6040, 0, self._on_controlword)
        if self._has_mode:
            node.add_write_listener(0x6060, 0, self._on_mode)
            node.add_validator(0x6060, 0, self._check_mode)
        node.add_reset_listener(self._reset)
        node.add_sync_listener(self._on_sync)
        node.on_comm_error.append(lambda _producer: self._abort_connection())
        node.add_nmt_listener(self._on_nmt)

    def _mode_display(self) -> int:
        return self.node.get(0x6061) if self._has_mode else self.mode

    # ------------------------------------------------------------------ state
    def _reset(self) -> None:
        # not ready to switch on -> switch on disabled happens by itself after the self-test
        self.state = DriveState.SWITCH_ON_DISABLED
        self._last_cw = self.node.get(0x6040)
        self._settled: DriveState | None = None  # a state the last controlword left as it was
        if self._has_mode:
            self.node.set(0x6061, 0, self.node.get(0x6060))
        self._publish()

    def _publish(self) -> None:
        sw = self.state.value | _REMOTE
        if self.state in _POWERED or self.state == DriveState.FAULT_REACTION_ACTIVE:
            sw |= _VOLTAGE_ENABLED
        if self.state == DriveState.OPERATION_ENABLED and self._mode_display() == self.mode:
            sw |= _FOLLOWS_COMMAND
        self.node.set(0x6041, 0, sw)

    @property
    def statusword(self) -> int:
        return self.node.get(0x6041)

    @property
    def operation_enabled(self) -> bool:
        return self.state == DriveState.OPERATION_ENABLED

    @property
    def quick_stop_active(self) -> bool:
        return self.state == DriveState.QUICK_STOP_ACTIVE

    @property
    def faulted(self) -> bool:
        return self.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)

    def _check_mode(self, value: int) -> int | None:
        bit = _MODE_BITS.get(value)
        if bit is None or (self.node.has(0x6502) and not self.node.get(0x6502) & bit):
            return ABORT_VALUE_RANGE
        return None

    def _on_mode(self, _key: tuple[int, int], value: int) -> None:
        # an RPDO bypasses the SDO validator: an unsupported mode is not displayed
        if self._check_mode(value) is None:
            self.node.set(0x6061, 0, value)
        self._publish()

    def _on_controlword(self, _key: tuple[int, int], cw: int) -> None:
        s = self.state
        if cw == self._last_cw and s is self._settled:
            # the same controlword again (every RPDO) in a state it already left unchanged:
            # it changes nothing again, and the status word is already published
            return
        rising_fault_reset = bool(cw & 0x80) and not self._last_cw & 0x80
        self._last_cw = cw
        if s == DriveState.FAULT:
            if rising_fault_reset:
                self._clear_fault()
        elif s == DriveState.FAULT_REACTION_ACTIVE:
            pass
        elif not cw & 0x02:  # disable voltage
            self.state = DriveState.SWITCH_ON_DISABLED
        elif not cw & 0x04:  # quick stop (active low)
            self.state = (DriveState.QUICK_STOP_ACTIVE if s == DriveState.OPERATION_ENABLED
                          else s if s == DriveState.QUICK_STOP_ACTIVE
                          else DriveState.SWITCH_ON_DISABLED)
        elif cw & 0x0F == 0x06:  # shutdown
            if s in (DriveState.SWITCH_ON_DISABLED, DriveState.SWITCHED_ON,
                     DriveState.OPERATION_ENABLED):
                self.state = DriveState.READY_TO_SWITCH_ON
        elif cw & 0x0F == 0x07:  # switch on / disable operation
            if s in (DriveState.READY_TO_SWITCH_ON, DriveState.OPERATION_ENABLED):
                self.state = DriveState.SWITCHED_ON
        elif cw & 0x0F == 0x0F:  # switch on + enable operation
            if s in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCHED_ON,
                     DriveState.QUICK_STOP_ACTIVE):
                self.state = DriveState.OPERATION_ENABLED
        self._publish()
        self._settled = s if self.state is s else None

    def _on_sync(self, _now_s: float) -> None:
        if self.state == DriveState.FAULT_REACTION_ACTIVE:
            self.state = DriveState.FAULT
            self._publish()

    def _on_nmt(self, _old: NmtState, new: NmtState) -> None:
        if new in (NmtState.STOPPED, NmtState.INITIALISING):
            self._abort_connection()

    def _abort_connection(self) -> None:
        if self.state not in _POWERED:
            return
        option = self.node.get(0x6007) if self.node.has(0x6007) else 1
        if option == 1:
            self.inject_fault(EMCY_HEARTBEAT)
        elif option == 2:
            self.state = DriveState.SWITCH_ON_DISABLED
        elif option == 3:
            if self.state == DriveState.OPERATION_ENABLED:
                self.state = DriveState.QUICK_STOP_ACTIVE
            elif self.state != DriveState.QUICK_STOP_ACTIVE:
                self.state = DriveState.SWITCH_ON_DISABLED
        self._publish()

    def disable_voltage(self) -> None:
        """The power stage off by the drive's own input (safe torque off), as a controlword
        with bit 1 clear would: switch on disabled, no EMCY; the master's enable operation
        alone does not bring it back (it needs a shutdown first)."""
        if self.state in _POWERED:
            self.state = DriveState.SWITCH_ON_DISABLED
            self._publish()

    def inject_fault(self, error_code: int = 0x2310) -> None:
        """A drive fault (default 0x2310 continuous overcurrent): fault bit, 0x603F, EMCY,
        torque off at once; 'fault' from the next SYNC until a fault reset (bit 7)."""
        if self.faulted:
            return
        self.state = DriveState.FAULT_REACTION_ACTIVE
        if self._has_error_code:
            self.node.set(0x603F, 0, error_code)
        self.node.set_error_bits(error_register_bits(error_code) | ERR_PROFILE)
        self._publish()
        self.node.emcy(error_code)

    def _clear_fault(self) -> None:
        self.state = DriveState.SWITCH_ON_DISABLED
        if self._has_error_code:
            self.node.set(0x603F, 0, 0)
        self.node.clear_error_bits(0xFF & ~ERR_GENERIC & ~0x10)
        self.node.emcy(EMCY_RESET)

    # ------------------------------------------------------------------ commands/actuals
    def _commanding(self) -> bool:
        return (self.state == DriveState.OPERATION_ENABLED
                and self._mode_display() == self.mode)

    def torque_command_per_mille(self) -> int:
        """Target torque 0x6071 limited to +-0x6072, or 0 unless operation enabled in CST."""
        if self.mode != MODE_CST or not self._commanding():
            return 0
        limit = self.node.get(0x6072) if self.node.has(0x6072) else 32767
        return _clamp(self.node.get(0x6071), -limit, limit)

    def target_velocity_raw(self) -> int:
        """Target velocity 0x60FF, or 0 unless operation enabled in CSV or PV."""
        if self.mode not in _VELOCITY_MODES or not self._commanding():
            return 0
        return self.node.get(0x60FF)

    def set_actuals(self, torque_per_mille: int, velocity_raw: int) -> None:
        """Torque actual 0x6077 (if the drive has it) and velocity actual 0x606C, saturated
        to their types."""
        if self.node.has(0x6077):
            self.node.set(0x6077, 0, _clamp(int(torque_per_mille), -32768, 32767))
        if self.node.has(0x606C):
            self.node.set(0x606C, 0, _clamp(int(velocity_raw), -(1 << 31), (1 << 31) - 1))


class Cia401Io:
    """CiA 401 I/O module: 8-bit digital outputs/inputs, 16-bit analog outputs/inputs.

    On a communication error (heartbeat consumer timeout) and when the node leaves
    operational (NMT stop, pre-operational, reset communication), outputs whose error mode
    is set (0x6206 bit, 0x6443 = 1) take their error values (0x6207, 0x6444) in the object
    dictionary; the master's next write replaces them."""

    def __init__(self, node: VirtualNode) -> None:
        # every CiA 401 object is optional: a module has the channels its EDS lists, and an
        # output without an error mode / value object (0x6206/0x6207, 0x6443/0x6444) keeps
        # its value on an error, as such a module does
        _integers(node, "CiA 401")
        self.node = node
        self.n_digital_out = self._count(0x6200)
        self.n_analog_in = self._count(0x6401)
        self.n_analog_out = self._count(0x6411)
        self.n_digital_in = self._count(0x6000)
        self.error_applied = 0
        node.on_comm_error.append(lambda _producer: self.apply_error_values())
        node.add_nmt_listener(self._on_nmt)

    def _count(self, index: int) -> int:
        """Channels of an array object: the subs 1.. the EDS declares."""
        n = 0
        while self.node.has(index, n + 1):
            n += 1
        return n

    def _on_nmt(self, old: NmtState, new: NmtState) -> None:
        if old == NmtState.OPERATIONAL and new in (NmtState.STOPPED, NmtState.PRE_OPERATIONAL,
                                                   NmtState.INITIALISING):
            self.apply_error_values()

    def apply_error_values(self) -> None:
        node = self.node
        for i in range(1, self.n_digital_out + 1):
            if not (node.has(0x6206, i) and node.has(0x6207, i)):
                continue
            mask = node.get(0x6206, i)
            node.set(0x6200, i, (node.get(0x6200, i) & ~mask) | (node.get(0x6207, i) & mask))
        for i in range(1, self.n_analog_out + 1):
            if node.has(0x6443, i) and node.has(0x6444, i) and node.get(0x6443, i):
                node.set(0x6411, i, _clamp(node.get(0x6444, i), -32768, 32767))
        self.error_applied += 1

    def digital_outputs(self, group: int = 1) -> int:
        """Output byte `group` (0x6200:group), bit 0 = output 1."""
        return self.node.get(0x6200, group)

    def analog_outputs(self) -> list[int]:
        return [self.node.get(0x6411, i) for i in range(1, self.n_analog_out + 1)]

    def set_analog_inputs(self, counts: list[int] | tuple[int, ...]) -> None:
        """Analog inputs 0x6401:1.. in counts, saturated to INTEGER16 (an ADC clips)."""
        if len(counts) > self.n_analog_in:
            raise ValueError(f"{len(counts)} analog inputs, the module has {self.n_analog_in}")
        for i, c in enumerate(counts, start=1):
            self.node.set(0x6401, i, _clamp(int(c), -32768, 32767))

    def set_digital_inputs(self, value: int, group: int = 1) -> None:
        if not 1 <= group <= self.n_digital_in:
            raise ValueError(f"digital input group {group}: the module has "
                             f"{self.n_digital_in}")
        self.node.set(0x6000, group, int(value) & 0xFF)


class Cia406Encoder:
    """CiA 406 multi-turn absolute rotary encoder: position 0x6004, speed 0x6030:1."""

    def __init__(self, node: VirtualNode) -> None:
        _require(node, [(0x6004, 0)], "CiA 406")  # the speed 0x6030 is optional
        _integers(node, "CiA 406")
        self.node = node
        self._signed = node.variable(0x6004).data_type in (0x2, 0x3, 0x4)

    def set_position(self, counts: int) -> None:
        """Position in counts; beyond the 32-bit range it wraps as the encoder's multi-turn
        counter does (the master unwraps)."""
        v = int(counts) & 0xFFFFFFFF
        if self._signed and v >= 1 << 31:
            v -= 1 << 32
        self.node.set(0x6004, 0, v)

    def set_speed(self, counts_per_s: int) -> None:
        """Speed in position counts per second, saturated to INTEGER32."""
        if not self.node.has(0x6030, 1):
            return
        self.node.set(0x6030, 1, _clamp(int(counts_per_s), -(1 << 31), (1 << 31) - 1))
