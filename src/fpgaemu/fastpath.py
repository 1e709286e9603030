"""The fused paths: an emulated millisecond's regular work, each piece in one Python frame.

A board's millisecond is nearly always the same work: the timer interrupt brings both
wheels up to the tick (:class:`~fpgaemu.motor.Motors`), samples the encoders' M/T speed,
runs the software speed PIDs, writes the PWM registers and sends ``TM`` through the TX
queue, ``uartsend`` and ``uartwrite``. Through the modules that is about 40 Python calls,
each re-reading the attributes the previous one had at hand (``benchmarks/ceiling.py``: the
modules cost 7.5× the arithmetic). :class:`FusedTick` does the same work written out in
one frame, with the objects looked up once per board.

Exactness is the contract: every stage here is the module's own code, the same operations
in the same order on the same objects, so registers, RAM, counters, floats to the last bit,
wire bytes and their cycles come out as the modules would leave them (``tests/fpgaemu/
test_fastpath.py`` compares two boards, one without the fused tick, state by state under
random traffic, faults and parameter changes). A stage whose regular pattern does not hold
this tick calls the module instead: the wheels under a body's physics, a stalled or loaded
wheel, Hall sensor noise, a controller other than the software speed loop, a TX line that
is busy, faulted or watched, a queue holding messages. Nothing is skipped or reordered, so
an irregular tick is the modules' tick.

The host's frames take two more: :func:`receive_idle` puts the host's bytes on a clean line
and hands them to the frame decoder (:meth:`Board.host_write`), and :func:`complete_frame`
completes the usual frame at its STOP (START, ordinary content, STOP in one run: the RX RAM,
the registers and the interrupt), where the modules take about 20 calls between them.

Measured (``python -m benchmarks.emulator``, the ``board.modules`` case beside ``board``):
see docs/emulator.md.
"""

from __future__ import annotations

from math import floor, radians
from typing import TYPE_CHECKING

from fpgaemu.motor import GEAR_RATIO, MAX_DUTY, PHYSICS_STEP_CYCLES, DrivenMotors, Motors
from fpgaemu.timeline import CLOCK_HZ, us
from fpgaemu.uart import ByteRun
from fpgaemu.uartcommand import _HUNT, RxInterrupt, UartCommand, _Cursor
from fpgalink.protocol import ChannelTelemetry, TelemetryFlags, encode_telemetry
from fpgalink.protocol.crc import append_crc
from fpgalink.protocol.params import BOARD, CHANNEL_A, CHANNEL_B

if TYPE_CHECKING:
    from fpgaemu.board import Board, ChannelIo
    from fpgaemu.encoder import QuadratureEncoder
    from fpgaemu.firmware import Channel, Firmware
    from fpgaemu.pwm import Pwm

__all__ = ["FusedTick", "complete_frame", "receive_idle"]

_CYCLES_PER_US = us(1)
_ENABLE, _END_STOP, _SATURATED = (int(f) for f in (
    TelemetryFlags.ENABLE, TelemetryFlags.END_STOP, TelemetryFlags.SATURATED))
_SPEED_SW = 0  # ActiveController: the firmware's speed PID (fpgaemu.firmware.SPEED_SW)
_new_tuple = tuple.__new__
_new_object = object.__new__


class FusedTick:
    """A firmware's timer tick, fused (see the module docstring). ``__call__(cycle)`` does
    the whole tick after the firmware's own preliminaries (booking finished frames, the
    quiescent check)."""

    def __init__(self, firmware: Firmware, board: Board) -> None:
        self.firmware = firmware
        self.board = board
        #: per channel, once the board is complete: the software's channel and its I/O
        self._channels: list[tuple[Channel, ChannelIo]] | None = None
        self._motors: Motors | None = None
        #: the motors, of either kind, whose ``advance_to`` is each PWM stage's listener
        self._wheels: Motors | DrivenMotors | None = None
        #: ticks done here (the rest went to the firmware's own tick)
        self.fused = 0

    def _wire(self) -> None:
        """Look the objects up once, at the first tick: the motors attach after the
        firmware, and a power cycle replaces the firmware (and with it this object)."""
        board, firmware = self.board, self.firmware
        self._channels = [(ch, board.channels[code]) for code, ch in firmware.channels.items()]
        motors = board.peripherals.get("motors")
        self._motors = motors if type(motors) is Motors else None
        self._wheels = motors if isinstance(motors, Motors | DrivenMotors) else None

    def __call__(self, cycle: int) -> bool:
        """Do the tick at ``cycle``; ``False`` (nothing done) when a channel runs a
        controller other than the software speed loop: the firmware's tick does it."""
        if self._channels is None:
            self._wire()
        firmware, board = self.firmware, self.board
        values, enabled = firmware.values, firmware._enabled
        if enabled and (values[(4, CHANNEL_A)] != _SPEED_SW
                        or values[(4, CHANNEL_B)] != _SPEED_SW):
            return False
        self.fused += 1
        # --- the wheels up to the tick (board.settle) -------------------------------------
        identified = self._motors
        if (identified is not None and len(board._settlers) == 1 and identified._noise is None
                and cycle - identified._cycle <= PHYSICS_STEP_CYCLES):
            _advance_identified(identified, board, cycle)
        else:
            board.settle(cycle)
        motors = self._wheels
        dt = board.timer.period_cycles / CLOCK_HZ
        telemetry = values[(2, BOARD)] == 1
        samples = []
        assert self._channels is not None
        for ch, io in self._channels:
            encoder = io.encoder
            pwm = io.pwm
            speed = encoder.firmware_reader.sample(cycle)
            ch.speed = speed
            # QuadratureEncoder.position, written out
            value = (encoder._count * encoder.direction) & 0xFFFF_FFFF
            ch.position = value - (1 << 32) if value & 0x8000_0000 else value
            ch.current = io.current_a
            if not enabled:
                ch.pid.reset()
                ch.current_pid.reset()
                _write_duty(pwm, 0, cycle, motors)
                saturated = False
            else:
                pid = ch.pid
                _write_duty(pwm, pid.update(ch.reference, speed, dt), cycle, motors)
                saturated = pid.saturated
            if telemetry:
                flags = _ENABLE if pwm.global_enable else 0
                if encoder.end_stop:
                    flags |= _END_STOP
                if saturated:
                    flags |= _SATURATED
                samples.append(_new_tuple(ChannelTelemetry, (
                    ch.position, speed, ch.current,
                    pwm.duty_register if pwm.global_enable else 0, ch.reference, flags)))
        firmware._timing.periods += 1
        if telemetry:
            content = encode_telemetry(firmware._counter.take(),
                                       ((cycle - firmware._powered_at) // _CYCLES_PER_US)
                                       & 0xFFFF_FFFF, *samples)
            if firmware.wire_crc.on:
                content = append_crc(content)
            if _send_idle(firmware, board, content, cycle) or firmware.tx.send(content, cycle):
                firmware.stats.telemetry_sent += 1
            else:
                firmware.stats.telemetry_dropped += 1
                firmware._timing.record_miss(cycle, None)
        return True


def _advance_identified(motors: Motors, board: Board, cycle: int) -> None:
    """:meth:`Motors.advance_to` for a tick at most one physics step after the last: each
    wheel's plant held over the step (:meth:`WheelPlant.hold`) and its encoder following
    (:meth:`QuadratureEncoder.follow`), written out."""
    start = motors._cycle
    if cycle <= start:
        return
    channels = board.channels
    dt = (cycle - start) / CLOCK_HZ
    for code, wheel in motors.wheels.items():
        io = channels[code]
        pwm = io.pwm
        wheel.duty = duty = pwm.duty_register if pwm.global_enable else 0
        x0, x1, x2 = wheel._x
        if (duty == 0 and wheel.current == 0.0 and wheel.load_torque_nm == 0.0
                and not (x0 or x1 or x2)):
            pass
        elif wheel.stalled or wheel.load_torque_nm:
            angle0 = wheel.angle_deg
            wheel.hold(dt)
            io.encoder.follow(start, angle0, cycle, wheel.angle_deg)
        else:
            angle0 = wheel.angle_deg
            # WheelPlant.hold, unloaded and free
            u = duty / MAX_DUTY
            (e0, g0, s0, i0), (e1, g1, s1, i1), (e2, g2, s2, i2) = (
                wheel._cache.get(dt) or wheel._coefficients(dt))
            angle_gain = 0.0 + (s0 * x0 + i0 * u).real
            angle_gain += (s1 * x1 + i1 * u).real
            angle_gain += (s2 * x2 + i2 * u).real
            wheel._x = [e0 * x0 + g0 * u, e1 * x1 + g1 * u, e2 * x2 + g2 * u]
            angle1 = wheel.angle_deg = angle0 + angle_gain
            # WheelPlant._follow_current
            m = wheel.motor
            decay = wheel._decay.get(dt)
            if decay is None:
                wheel._follow_current(dt, angle_gain / dt)
            else:
                steady = (m.supply_v * duty / MAX_DUTY
                          - m.ke_v_s_per_rad * (radians(angle_gain / dt) * GEAR_RATIO)
                          ) / m.resistance_ohm
                wheel.current = steady + (wheel.current - steady) * decay
            if not u:
                wheel._come_to_rest()
                angle1 = wheel.angle_deg
            _follow(io.encoder, start, angle0, cycle, angle1)
        io.current_a = wheel.current
    motors._cycle = cycle


def _follow(enc: QuadratureEncoder, cycle0: int, angle0: float, cycle1: int, angle1: float
            ) -> None:
    """:meth:`QuadratureEncoder.follow` when no count boundary was crossed (the rest is the
    module's)."""
    counts = enc.counts_per_turn
    if counts > 0:
        offset = enc._angle_offset
        if (floor((angle0 - offset) * counts / 360.0)
                == floor((angle1 - offset) * counts / 360.0)):
            enc._angle = angle1
            return
    enc.follow(cycle0, angle0, cycle1, angle1)


def _write_duty(pwm: Pwm, duty: int, cycle: int, motors: Motors | DrivenMotors | None
                ) -> None:
    """:meth:`Pwm.write_duty`. Its listener is the motors' ``advance_to``, which the settle
    at this tick has already brought to ``cycle`` (a call would return at once), so it is
    not called then."""
    value = int(duty)
    if value > MAX_DUTY:
        value = MAX_DUTY
    elif value < -MAX_DUTY:
        value = -MAX_DUTY
    if value != pwm.duty_register:
        listeners = pwm._listeners
        if not (motors is not None and len(listeners) == 1 and motors._cycle >= cycle
                and getattr(listeners[0], "__self__", None) is motors):
            for listener in listeners:
                listener(cycle)
        pwm.duty_register = value


def _send_idle(firmware: Firmware, board: Board, content: bytes, cycle: int) -> bool:
    """:meth:`TxQueue.send` → :meth:`UartSend.load_and_strobe` → :meth:`UartWrite.transmit`
    for the usual case, written out: nothing queued, the line idle, clean and unwatched.
    ``False`` (nothing done) otherwise: the caller then sends through the modules."""
    tx = firmware.tx
    uartsend = board.uartsend
    uartwrite = board.uartwrite
    bram = uartsend.bram
    n = len(content)
    if (tx._queue or cycle < uartsend.busy_until or uartsend.frame_filter is not None
            or uartsend._done_listeners or uartwrite.faults is not None
            or uartwrite.receiver._bursts or not uartwrite._last_level or n > bram.size
            or board.timeline.now != cycle):
        return False
    bram._mem[0:n] = content
    uartsend.length = n
    wire = uartsend._escaper.frame(content)
    wire_bytes = len(wire)
    stats = uartsend.stats
    stats.frames += 1
    stats.wire_bytes += wire_bytes
    stats.escapes += wire_bytes - n - 2
    # UartWrite._send, clean and idle
    line_stats = uartwrite.stats
    start = max(cycle, uartwrite.line_free_at)
    line_stats.bytes_sent += wire_bytes
    step = uartwrite.byte_step
    done = uartwrite.line_free_at = start + wire_bytes * step - uartwrite.byte_gap
    uartwrite._last_level = 1
    line_stats.bytes_received += wire_bytes
    run = _new_tuple(ByteRun, (wire, start + uartwrite.cycles_per_byte, step))
    uartwrite._pending.append(run)
    for listener in uartwrite._listeners:
        listener(run)
    uartsend.busy_until = done
    uartsend.frame_wire_bytes = wire_bytes
    tx.stats.sent += 1
    firmware._in_flight.append((done, wire_bytes, cycle))
    return True


# --- the host's frames: a clean line into the frame decoder ----------------------------------


def receive_idle(board: Board, data: bytes | bytearray | memoryview, cycle: int | None
                 ) -> int | None:
    """:meth:`Board.host_write` → :meth:`UartRead.transmit` → :meth:`UartCommand.receive`
    for a line without faults, written out: the run of bytes with its completion cycles,
    handed to the frame decoder. ``None`` (nothing done) for anything else: a faulted line,
    nothing to send, a cycle in the past (the module raises)."""
    line = board.uartread
    now = board.timeline.now
    at = now if cycle is None else cycle
    if line.faults is not None or not data or at < now:
        return None
    # Without faults the receiver never holds slots and the line ends high: UartRead._send's
    # bit-level branch cannot be taken.
    content = bytes(data)
    n = len(content)
    start = max(at, line.line_free_at)
    stats = line.stats
    stats.bytes_sent += n
    step = line.byte_step
    done = line.line_free_at = start + n * step - line.byte_gap
    line._last_level = 1
    stats.bytes_received += n
    command = board.uartcommand
    cursor = _new_object(_Cursor)
    cursor.run = _new_tuple(ByteRun, (content, start + line.cycles_per_byte, step))
    cursor.pos = 0
    command._runs.append(cursor)
    command._stats.bytes_received += n
    if command._candidate is None:
        command._arm()
    return done


def complete_frame(command: UartCommand, cycle: int) -> bool:
    """:meth:`UartCommand._on_candidate` for the usual frame, written out: the decoder
    hunting and the oldest run holding exactly START, three or more ordinary content bytes
    and the STOP now completing (later runs may wait behind it); the content into the RX
    RAM's write half, the registers, the next STOP armed, the interrupt to the processor.
    ``False`` (nothing done) for anything else: escapes, noise, a frame split over runs, a
    direct command, a frame filter, an empty or oversized frame."""
    runs = command._runs
    cursor = command._candidate_cursor
    if (cursor is None or not runs or runs[0] is not cursor or cursor.pos
            or command._state != _HUNT or command.frame_filter is not None or command._due):
        return False
    data = cursor.run.data
    index = command._candidate_index
    length = index - 1
    if (index != len(data) - 1 or data[0] != command.framing.start or length <= 2
            or length > command._limit):
        return False
    match = command._ordinary_run(data, 1, index)
    if match is None or match.end() != index:
        return False
    command._candidate = None
    command._candidate_cursor = None
    # _process's usual case: _store, then _complete
    half = command._write_half
    owned = command._owned
    stats = command._stats
    if owned[half]:
        owned[half] = False
        stats.overruns += 1
    base = half * command.half_size
    command.bram._mem[base:base + length] = data[1:index]
    owned[half] = True
    command._write_half = half ^ 1
    command.start_address = base
    command.length = length
    stats.frames += 1
    cursor.pos = index + 1
    runs.popleft()
    if runs:
        command._arm()
    interrupt = _new_tuple(RxInterrupt, (cycle, base, length))
    for listener in command._rx_listeners:
        listener(interrupt)
    return True
