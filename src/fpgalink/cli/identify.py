"""``identify``: excite one channel, record it, fit the plant in the seed's model form and
print the fit (docs/hardware.md, "Bring-up checklist")."""

from __future__ import annotations

import asyncio
import datetime
import signal
from pathlib import Path
from typing import TYPE_CHECKING

import click

from fpgalink.bringup.session import ChannelRecord
from fpgalink.cli.bringup import (
    Identification,
    Recorder,
    fit_document,
    fit_record,
    identification,
    identification_options,
    identify_on,
    print_fit,
    record_from_file,
    recording,
    save_fit_plot,
    write_text,
)
from fpgalink.cli.figures import check_plot_path
from fpgalink.cli.files import check_output, force_option
from fpgalink.cli.formats import format_option
from fpgalink.cli.liveview import add_live_boards, foxglove_option, opened_live
from fpgalink.cli.options import ConnectionOptions, announce_emulator, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, note
from fpgalink.cli.session import install_stop_signals, run
from fpgalink.protocol import identity_metadata

if TYPE_CHECKING:
    from fpgalink.live import LiveAddress

__all__ = ["identify"]


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--channel", "-c", type=click.Choice(["A", "B"], case_sensitive=False),
              required=True, help="The channel (wheel) to identify.")
@identification_options
@click.option("--from", "from_file", type=click.Path(exists=True, dir_okay=False,
                                                     path_type=Path),
              help="Fit a recording (identify --record, record) instead of driving a board.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path),
              help="Save measured against simulated speed, the step response and the Bode "
                   "plot to a .png/.svg/.pdf.")
@click.option("--save-model", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the fitted model (TOML) for autotune --model.")
@force_option
@foxglove_option
@format_option
@connection_options(announce=False)
def identify(channel: str, wheels: str | None, max_duty: float | None, duration: float,
             bit_s: float, period_ms: int, orders: tuple[int, int, int], offset: bool,
             record: Path | None, from_file: Path | None, plot: Path | None,
             save_model: Path | None, force: bool, foxglove: LiveAddress | None, fmt: str,
             conn: ConnectionOptions) -> int:
    """Identify one wheel's plant: duty in, speed out, fitted in the seed's form.

    Needs --wheels (air: the robot on blocks; ground) and --max-duty (the largest duty the
    run may apply); refuses a board that does not show itself enabled. The duty steps as a
    pseudo-random binary sequence for --duration s (the speed PID made a unit gain: open
    loop), TsTimerPeriod at --period-ms; everything changed is set back and the board
    disabled at the end, on Ctrl-C and on SIGTERM (exit 130, 143). Prints the model (B/F,
    DC gain, poles, delay), a first-order-plus-dead-time summary and the fit on the last
    30 % of the data, held out. --record, --plot and --save-model are refused if they exist
    (checked before the board is driven) unless --force; a full disk stops the run (exit
    1, the recording complete up to there). --from reads a recording with every chunk
    checked: damage is named, what is intact fitted, and the exit is 9.
    """
    channel = channel.upper()
    options = identification(wheels, max_duty, duration, bit_s, period_ms, orders, offset,
                             driving=from_file is None)
    if plot is not None:
        check_plot_path(plot, force=force)
    if save_model is not None:
        check_output(save_model, force=force)
    damaged = 0
    if from_file is not None:
        if record is not None or foxglove is not None:
            raise CliError("--record or --foxglove with --from: --from reads a recording, it "
                           "drives no board", ExitCode.BAD_INPUT)
        board, channel_record, damaged = record_from_file(from_file, conn.settings.board,
                                                          channel)
        where = f"{from_file}"
    else:
        if record is not None:
            check_output(record, force=force)
        announce_emulator(conn)
        endpoint = conn.single
        board = endpoint.name
        where = endpoint.url
        outcome = run(_identify(conn, channel, options, record, force, foxglove),
                      endpoint.url)
        if not isinstance(outcome, ChannelRecord):
            note(f"interrupted by {signal.Signals(outcome - 128).name}: the board was "
                 "disabled, its parameters set back; nothing fitted")
            return outcome
        channel_record = outcome
    fit = fit_record(channel_record, options, where)
    document = fit_document(fit, board, channel)
    print_fit(fmt, [document])
    if save_model is not None:
        _save_model(save_model, fit, where, channel, options, force)
    if plot is not None:
        save_fit_plot(plot, channel_record, fit, f"board {board} channel {channel}: "
                      f"{fit.fit_percent:.1f} % fit on held-out data", force=force)
        note(f"plot saved to {plot}")
    if damaged:
        raise CliError(f"{from_file}: damaged: {damaged} part(s) skipped (named above); "
                       "fitted what is intact", ExitCode.DAMAGED)
    return ExitCode.OK


def _save_model(path: Path, fit: object, where: str, channel: str,
                options: Identification, force: bool) -> None:
    from fpgalink.bringup.modelfile import model_to_toml
    from fpgalink.bringup.plant import PlantFit

    assert isinstance(fit, PlantFit)
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    text = model_to_toml(fit.model, f"{where} channel {channel}, wheels {options.where}, "
                         f"fpgalink-cli identify, {when}",
                         {"fit_percent": fit.fit_percent, "residual_dps": fit.residual,
                          "wheels": options.wheels, "channel": channel})
    write_text(path, text, force=force)
    note(f"model saved to {path}")


async def _identify(conn: ConnectionOptions, channel: str, options: Identification,
                    record: Path | None, force: bool, foxglove: LiveAddress | None
                    ) -> ChannelRecord | int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    endpoint = conn.single
    async with conn.link(endpoint) as link, \
            opened_live(foxglove, "fpgalink-cli identify") as view:
        add_live_boards(view, {endpoint.name: link})
        # Opened once the board said who it is: the file says it, beside this host's hash.
        recorder = None if record is None else Recorder(
            record, [endpoint.name], {
                "command": "identify", "channel": channel, "wheels": options.wheels,
                "max_duty_percent": f"{options.max_duty:g}",
                "period_ms": str(options.period_ms),
                **identity_metadata({endpoint.name: (link.identification.identity,
                                                     link.identification.known)})},
            stop, force=force)
        with recording(recorder):
            result = await identify_on(link, endpoint.name, channel, options, stop, recorder)
    fired = getattr(stop, "signal", None)
    return 128 + int(fired) if fired is not None else result
