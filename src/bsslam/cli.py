"""The ``bsslam`` command line: thin verbs over library functions."""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import json
import logging
import os
import signal
import sys
import threading
from enum import Enum
from pathlib import Path
from typing import Iterator, List, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Column, Table
from typer.core import TyperGroup

from bsslam import __version__
from bsslam.errors import BsslamError, ConfigError

# Set by the app's callback for this invocation: -q hides the progress bars too.
_quiet = False
_LATE_FLAGS = "bsslam.verbosity_after_verb"  # key in click's context meta


def _set_verbosity(verbose: bool, quiet: bool) -> None:
    """-v: log INFO and up; -q: only errors, and no progress bars; else warnings and up."""
    global _quiet
    if verbose and quiet:
        raise typer.BadParameter("give -v or -q, not both")
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")  # once: later calls do nothing
    level = logging.INFO if verbose else logging.ERROR if quiet else logging.WARNING
    logging.getLogger().setLevel(level)
    # Dask's scheduler and workers log their start and stop at INFO (some 30 lines a run),
    # not the details -v asks for. Dask sets its loggers' levels from its configuration
    # when it is imported (later, by the runner; the environment reaches the workers too).
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    logging.getLogger("distributed").setLevel(max(level, logging.WARNING))
    _quiet = quiet


class _App(TyperGroup):
    """The ``bsslam`` command: -v/-q are taken after the verb too (``bsslam run x.clf -q``).

    They are picked out of the verb's arguments (up to a ``--``) here, before the app's
    callback runs, which then applies them with its own."""

    _FLAGS = {"-v": "verbose", "--verbose": "verbose", "-q": "quiet", "--quiet": "quiet"}

    def resolve_command(self, ctx, args):
        name, command, rest = super().resolve_command(ctx, args)
        end = rest.index("--") if "--" in rest else len(rest)
        ctx.meta[_LATE_FLAGS] = {self._FLAGS[a] for a in rest[:end] if a in self._FLAGS}
        return name, command, [a for a in rest[:end] if a not in self._FLAGS] + rest[end:]


class _CommandLine(typer.Typer):
    """The app as the ``bsslam`` command calls it: its exit skips the interpreter's teardown.

    Freeing the ~1500 modules a run imports (numba, LLVM, gtsam, scipy, matplotlib) and
    its objects took half a second to a second after the results were written. On the
    command line (``app()``, reading ``sys.argv``) the exit runs the ``atexit`` handlers
    (logging, rerun, temporary folders), flushes stdout and stderr and ends the process.
    It exits the ordinary way when another non-daemon thread is alive (the interpreter
    would wait for it), for args given in Python and in an interactive session; the
    typer test runner calls the command object, not this."""

    def __call__(self, *args, **kwargs):
        try:
            return super().__call__(*args, **kwargs)
        except SystemExit as exc:
            if args or kwargs.get("args") is not None or hasattr(sys, "ps1") or sys.flags.interactive:
                raise
            if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
                raise
            _exit_now(exc.code)


def _exit_now(code) -> None:
    """What ``sys.exit(code)`` ends with, in its order, minus the teardown: the code (a
    non-integer printed to stderr, exit status 1), the ``atexit`` handlers, the flushed
    streams."""
    import atexit

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        print(code, file=sys.stderr)
        status = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe (| head) or stream: nothing to flush into
            pass
    os._exit(status & 0xFF)   # what the shell sees of any status


app = _CommandLine(cls=_App, add_completion=False, no_args_is_help=True,
                   help="BS-SLAM: EKF SLAM with B-spline map features for 2D laser range finders.")
experiment_app = typer.Typer(no_args_is_help=True, help="Reproduce the paper's experiments.")
app.add_typer(experiment_app, name="experiment")
console = Console(stderr=True)

OUT_HELP = ("Results folder: files go to DIR/<timestamp>/; DIR/latest points at the newest "
            "complete run.")
EXIT_INTERRUPTED = 130   # 128 + SIGINT, what shells report for a Ctrl-C
WORKERS_HELP = ("Runs in parallel on a local Dask cluster of N processes (default: one per core); "
                "1 = one after the other in this process.")
SCHEDULER_HELP = "Address of a running Dask scheduler (e.g. tcp://host:8786): the runs go to its workers."


_compile_hint_shown = False


@contextlib.contextmanager
def progress_bar(description: str, total: int | None, unit: str = "") -> Iterator:
    """A rich progress bar; yields ``update(done, total)`` for library callbacks. Before the
    first bar of a machine's first run, says why it will wait at the start."""
    global _compile_hint_shown
    if not _compile_hint_shown and not _quiet:
        _compile_hint_shown = True
        from bsslam.compiled import needs_compiling
        from bsslam.slam.range_kernels import linearize_beams   # one of the filter's kernels

        if needs_compiling(linearize_beams):
            console.print("[dim]first run on this machine: compiling the inner loops "
                          "(about a minute; cached for the next runs)[/dim]")
    columns = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, console=console, disable=_quiet) as bar:
        task = bar.add_task(description, total=total, rate="")

        def update(done: int, total_: int | None = None) -> None:
            _deliver_swallowed_signal()
            elapsed = bar.tasks[0].elapsed or 0.0
            rate = f"{done / elapsed:.1f} {unit}/s" if unit and elapsed > 0 else ""
            bar.update(task, completed=done, total=total_ if total_ is not None else total, rate=rate)

        def restart(description_: str, total_: int | None) -> None:
            bar.reset(task, total=total_, description=description_)

        update.restart = restart  # type: ignore[attr-defined]
        yield update


def next_phase(update, description: str):
    """A progress callback that, on its first call, turns ``update``'s bar into a new phase."""
    started = False

    def progress(done: int, total: int | None) -> None:
        nonlocal started
        if not started:
            update.restart(description, total)
            started = True
        update(done, total)

    return progress


def fail(exc: Exception) -> None:
    # unwrapped and unparsed: the message names files and lines, which must stay whole (and
    # copyable) whatever the terminal width, and a "[…]" in a path is not rich markup
    console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)
    raise typer.Exit(2)


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """While inside, SIGTERM (and SIGINT) raise KeyboardInterrupt naming the signal, so a
    ``kill`` ends a run as cleanly as a Ctrl-C: the run folder is marked and what results
    exist are written. Only the main thread may set handlers; elsewhere this does nothing.

    On entry it loads numba's implementations (:func:`bsslam.compiled.load_compiler_registries`)
    with the signals held: a signal raised while numba half-loads them would break every
    kernel call after it, the writing of the results so far included. Signals are held too
    while numba compiles or loads a kernel (its compiler lock): raised in one of LLVM's
    callbacks into Python, the KeyboardInterrupt leaves LLVM's object cache inconsistent
    and the process aborts (SIGABRT) at the next code generation; the signal is raised
    once the compilation is done. A signal that lands in numba's Python code called back
    from a running kernel (boxing its result) would come out of the kernel as a
    SystemError; it is held and raised by the next progress callback."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from numba.core import event as numba_event

    from bsslam.compiled import load_compiler_registries

    holding = False
    compiling = 0      # depth of numba's (re-entrant) compiler lock
    held_in_compile = False   # a signal came while it was held

    class CompilerLockListener(numba_event.Listener):
        def on_start(self, event):
            nonlocal compiling
            compiling += 1

        def on_end(self, event):
            nonlocal compiling, held_in_compile
            compiling -= 1
            if compiling == 0 and held_in_compile and not holding:
                # the kernel is whole and numba's lock released: the held signal is raised
                # now (only one held here: one that already reached the run ended it, and
                # raising it again would cut short the writing of the results so far)
                held_in_compile = False
                _deliver_swallowed_signal()

    def interrupt(signum, frame):
        nonlocal held_in_compile
        name = signal.Signals(signum).name
        _signalled.append(name)
        if compiling:
            held_in_compile = True
        elif not holding and not _in_numba(frame):
            raise KeyboardInterrupt(name)
        # in numba's own Python code (a compiled kernel boxing its result calls back into
        # it) the exception would come out as a SystemError that no interruption handler
        # recognises: held, the next progress callback raises it

    def unraisable(info):
        # the signal's KeyboardInterrupt raised inside a ctypes callback (numba compiling)
        # is dropped by the interpreter, which would print it as a traceback; it is kept in
        # _signalled and delivered again by the next progress callback, so say nothing
        if isinstance(info.exc_value, KeyboardInterrupt) and _signalled:
            return
        previous_hook(info)

    listener = CompilerLockListener()
    numba_event.register("numba:compiler_lock", listener)
    previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    previous_hook, sys.unraisablehook = sys.unraisablehook, unraisable
    try:
        holding = True    # a signal now is raised once numba's tables are whole
        load_compiler_registries()
        holding = False
        _deliver_swallowed_signal()
        yield
    finally:
        _signalled.clear()
        sys.unraisablehook = previous_hook
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        numba_event.unregister("numba:compiler_lock", listener)


#: Signals the handler raised for or held. A KeyboardInterrupt raised while the interpreter
#: is in a ctypes callback (numba compiling a kernel calls back into Python) is printed and
#: dropped, and one in numba's own Python code is held, so the run would go on; the
#: progress callbacks deliver it (again).
_signalled: list[str] = []


def _in_numba(frame) -> bool:
    """Whether the interpreter is inside numba's own Python code (``frame`` or a caller):
    a compiled kernel calls back into it, e.g. to box the arrays it returns."""
    import numba

    root = os.path.dirname(numba.__file__) + os.sep
    while frame is not None:
        if frame.f_code.co_filename.startswith(root):
            return True
        frame = frame.f_back
    return False


def _deliver_swallowed_signal() -> None:
    """Raise the KeyboardInterrupt of a signal whose first raise went nowhere (once)."""
    if _signalled:
        raise KeyboardInterrupt(_signalled.pop())


def interrupted(run_dir: Path | None, reason: str) -> None:
    """One line on stderr and exit 130."""
    where = (f": {run_dir} is marked interrupted; {run_dir.parent / 'latest'} stays on the last complete run"
             if run_dir is not None else "")
    console.print(f"[yellow]{escape(reason)}[/yellow]{escape(where)}", soft_wrap=True)
    raise typer.Exit(EXIT_INTERRUPTED)


@contextlib.contextmanager
def experiment_folder(out: Path, summary: dict) -> Iterator[Path]:
    """The run folder of an experiment verb: yields it for the files; on a clean exit writes
    ``summary.json`` (``summary`` plus status complete) and publishes the folder as
    ``latest``; an interruption exits 130 and a BsslamError 2, the folder marked."""
    from bsslam.io.results import interrupt_reason, run_folder, write_summary

    run_dir = None
    try:
        with signals_interrupt(), run_folder(out) as run_dir:
            yield run_dir
            write_summary(run_dir, summary, "complete")
    except KeyboardInterrupt as exc:
        interrupted(run_dir, interrupt_reason(exc))
    except BsslamError as exc:
        fail(exc)


def exit_if_partial(summary: dict, run_dir: Path) -> None:
    """A partial result (the scans before an interruption, written and marked) exits 130."""
    if summary.get("status") == "interrupted":
        interrupted(run_dir, summary.get("reason", "interrupted"))


def print_summary(summary: dict, title: str) -> None:
    table = Table(title=title, show_header=False)
    for key, value in summary.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items()) or "-"
        table.add_row(key, str(value))
    Console().print(table)


def _load_config(config_file: Optional[Path]):
    from bsslam.config import SLAMConfig
    from bsslam.io.config_file import load_config

    return load_config(config_file) if config_file else SLAMConfig()


BACKEND_HELP = ("submaps (default): local submaps tied by a pose graph with loop closures, bounded memory "
                "and time per scan; ekf: the paper's single global EKF. Default: the configuration's.")
MAX_MEMORY_HELP = ("Budget for the estimator's live arrays (MB); past it the run stops with a message and writes "
                   "its results so far. Default: the configuration's max_memory_mb (1024).")


def _overridden(config, mode: Optional[str] = None, backend: Optional[str] = None,
                max_memory: Optional[float] = None):
    """``config`` with the command line's overrides (checked as the configuration file's are)."""
    from bsslam.config import SLAMConfig

    data = config.to_dict()
    for key, value in (("mode", mode), ("backend", backend), ("max_memory_mb", max_memory)):
        if value is not None:
            data[key] = value
    return SLAMConfig.from_dict(data)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"bsslam {__version__}")
        raise typer.Exit()


@app.callback()
def main(ctx: typer.Context,
         verbose: bool = typer.Option(False, "--verbose", "-v", help="Log details to stderr (before or after the verb)."),
         quiet: bool = typer.Option(False, "--quiet", "-q", help="Only errors: no progress bars, no notices "
                                    "(before or after the verb)."),
         version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                      help="Print the version and exit.")) -> None:
    late = ctx.meta.get(_LATE_FLAGS, set())
    _set_verbosity(verbose or "verbose" in late, quiet or "quiet" in late)


# --------------------------------------------------------------------------------------
@app.command()
def simulate(
    world: str = typer.Option("rounded-room", help="Built-in world (see --list)."),
    seed: int = typer.Option(0, help="Random seed of the simulated noise."),
    steps: Optional[int] = typer.Option(None, min=1, help="Number of scans (default: the whole double loop)."),
    out: Path = typer.Option(Path("results/simulate"), help=OUT_HELP),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration of the filter."),
    backend: Optional[str] = typer.Option(None, metavar="submaps|ekf", help=BACKEND_HELP),
    max_memory: Optional[float] = typer.Option(None, "--max-memory", metavar="MB", help=MAX_MEMORY_HELP),
    list_worlds: bool = typer.Option(False, "--list", help="List the built-in worlds and exit."),
    viewer: Optional[str] = typer.Option(None, metavar="spawn|save",
                                         help="Show the run in rerun: spawn (live, in the viewer app) or save "
                                              "(viewer.rrd in the results folder); pip install 'bsslam\\[viewer]'."),
    show_control_points: bool = typer.Option(True, "--show-control-points/--hide-control-points",
                                             help="Draw the splines' control points in map.png/map.svg."),
) -> None:
    """One SLAM run in a simulated world with exact ground truth."""
    from bsslam.experiments.consistency import simulation_config
    from bsslam.io.results import interrupt_reason, run_folder
    from bsslam.outputs import write_outputs
    from bsslam.pipeline import run_dataset
    from bsslam.sim import WORLDS, SimConfig, get_world, simulate as simulate_world
    from bsslam.viz.rerun_viewer import open_viewer

    if list_worlds:
        for name, w in WORLDS.items():
            typer.echo(f"{name:15s} {w.description}")
        return
    run_dir = None
    try:
        with signals_interrupt():
            sim = SimConfig()
            config = simulation_config(_overridden(_load_config(config_file), None, backend, max_memory), sim)
            data = simulate_world(get_world(world), sim, seed=seed, steps=steps)
            with run_folder(out) as run_dir:
                with progress_bar(f"SLAM in {world}", len(data.ground_truth), "scans") as update:
                    result = run_dataset(data, config, progress=update, total=len(data.ground_truth),
                                         viewer=open_viewer(viewer, run_dir) if viewer else None)
                summary = write_outputs(result, run_dir, config, walls=data.world.polylines(0.02), exact_reference=True,
                                        title=f"BS-SLAM in the simulated world '{world}' (seed {seed})",
                                        show_control_points=show_control_points)
    except KeyboardInterrupt as exc:
        interrupted(run_dir, interrupt_reason(exc))
    except BsslamError as exc:
        fail(exc)
    print_summary(summary, f"bsslam simulate --world {world}")
    exit_if_partial(summary, run_dir)
    console.print(f"results in [bold]{run_dir}[/bold] (map picture: {run_dir / 'map.png'})")


CHECKPOINT_HELP = ("Save the run's whole state to checkpoint.pkl in its results folder every N scans, every "
                   "N seconds (e.g. 60s) or never (0), so that --resume can finish a killed run with the same "
                   "results. Removed when the run completes.")
RESUME_HELP = ("Continue the run in this results folder from its last checkpoint (log and options from the "
               "checkpoint; no LOG): the same trajectory and map as a run never stopped.")
PARALLEL_HELP = ("Read the log and run the scan-matching front end in a second process, ahead of the filter "
                 "(with two or more cores): the same results, sooner.")
#: run's options that --resume takes from the checkpoint, with their flags
_RESUME_FIXED = {"log": "LOG", "config_file": "--config", "out": "--out", "mode": "--mode", "backend": "--backend",
                 "max_memory": "--max-memory", "fmt": "--format", "strict": "--strict", "steps": "--steps",
                 "reference": "--reference", "scan_topic": "--scan-topic", "odom_topic": "--odom-topic",
                 "viewer": "--viewer", "show_control_points": "--show-control-points"}


def _on_command_line(ctx: typer.Context, name: str) -> bool:
    """Whether the option ``name`` was given on the command line (not its default)."""
    source = ctx.get_parameter_source(name)
    # by name: typer may vendor its own click, whose ParameterSource is another enum
    return source is not None and source.name == "COMMANDLINE"


@app.command()
def run(
    ctx: typer.Context,
    log: Optional[Path] = typer.Argument(None, help="CARMEN log (.clf/.log), ROS 1 bag (.bag), ROS 2 bag folder, "
                                         "or a folder of logs: each is run, its results under OUT/<log name>/."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration of the filter."),
    out: Path = typer.Option(Path("results/run"), help=OUT_HELP),
    mode: Optional[str] = typer.Option(None, help="slam (default) or localization."),
    backend: Optional[str] = typer.Option(None, metavar="submaps|ekf", help=BACKEND_HELP),
    max_memory: Optional[float] = typer.Option(None, "--max-memory", metavar="MB", help=MAX_MEMORY_HELP),
    fmt: Optional[str] = typer.Option(None, "--format", help="carmen, ros1 or ros2 (default: from the path)."),
    strict: bool = typer.Option(False, help="Stop at the first bad input line instead of skipping it."),
    steps: Optional[int] = typer.Option(None, min=1, help="Process only the first N scans."),
    reference: Optional[Path] = typer.Option(None, help="Reference trajectory (TUM or 't x y θ') for ATE."),
    scan_topic: Optional[str] = typer.Option(None, help="ROS: LaserScan topic (default: auto)."),
    odom_topic: Optional[str] = typer.Option(None, help="ROS: Odometry topic (default: auto, else /tf)."),
    viewer: Optional[str] = typer.Option(None, metavar="spawn|save",
                                         help="Show the run in rerun: spawn (live, in the viewer app) or save "
                                              "(viewer.rrd in the results folder); pip install 'bsslam\\[viewer]'."),
    show_control_points: bool = typer.Option(False, "--show-control-points",
                                             help="Draw the splines' control points in map.png/map.svg."),
    checkpoint_every: str = typer.Option("60s", metavar="N|Ns|0", help=CHECKPOINT_HELP),
    resume: Optional[Path] = typer.Option(None, metavar="RUN_DIR", help=RESUME_HELP),
    parallel: bool = typer.Option(True, "--parallel/--no-parallel", help=PARALLEL_HELP),
) -> None:
    """Run BS-SLAM on a laser log and write trajectory, map, grid and pictures."""
    options = dict(locals())  # every option of this call, for the runs of a folder's logs
    from bsslam.io.checkpoint import CheckpointEvery
    from bsslam.io.log_paths import find_logs, is_ros2_bag

    try:
        every = CheckpointEvery.parse(checkpoint_every)
        if resume is not None:
            given = [flag for name, flag in _RESUME_FIXED.items() if _on_command_line(ctx, name)]
            if given:
                raise ConfigError(f"--resume takes the log and options from the checkpoint: drop {', '.join(given)}")
        elif log is None:
            raise ConfigError("name the LOG to run (or --resume RUN_DIR)")
    except BsslamError as exc:
        fail(exc)
    if resume is not None:
        _resume_run(resume, every if _on_command_line(ctx, "checkpoint_every") else None, parallel)
        return
    if log.is_dir() and not is_ros2_bag(log):
        try:
            logs = find_logs([log])
        except BsslamError as exc:
            fail(exc)
        for one in logs:
            run(**{**options, "log": one, "out": out / one.stem})
        return
    from bsslam.io.checkpoint import CheckpointHeader
    from bsslam.io.results import interrupt_reason, run_folder

    run_options = {"fmt": fmt, "strict": strict, "steps": steps, "scan_topic": scan_topic, "odom_topic": odom_topic,
                   "reference": None if reference is None else os.fspath(reference.resolve()),
                   "show_control_points": show_control_points}
    place: dict = {}
    try:
        with signals_interrupt():
            config = _overridden(_load_config(config_file), mode, backend, max_memory)
            header = CheckpointHeader(log=os.fspath(log.resolve()), log_sha256="", config=config.to_dict(),
                                      options=run_options)
            # the folder is made only once the log opens
            _run_log(header, config, lambda: run_folder(out), every, viewer, place, parallel=parallel)
    except KeyboardInterrupt as exc:
        interrupted(place.get("run_dir"), interrupt_reason(exc))
    except BsslamError as exc:
        fail(exc)


@contextlib.contextmanager
def _frozen_heap() -> Iterator[None]:
    """While inside, the objects that exist now (mostly the imported modules', hundreds of
    thousands) are left out of the garbage collector's full passes: a run allocates enough
    to trigger a few, and each walked them all (~0.1 s apiece on intel)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _resume_run(run_dir: Path, every, parallel: bool = True) -> None:
    """``bsslam run --resume RUN_DIR``: the run in RUN_DIR continued from its checkpoint,
    with its log and options (and its checkpoint interval unless ``every`` is given)."""
    from bsslam.config import SLAMConfig
    from bsslam.io.checkpoint import CheckpointEvery, check_source, read_header
    from bsslam.io.results import interrupt_reason, resumed_run_folder

    try:
        with signals_interrupt():
            header = read_header(run_dir)
            check_source(header)
            config = SLAMConfig.from_dict(header.config)
            every = every if every is not None else CheckpointEvery.parse(header.options.get("checkpoint_every", "60s"))
            _run_log(header, config, lambda: resumed_run_folder(run_dir), every, None, {}, resume=True,
                     parallel=parallel)
    except KeyboardInterrupt as exc:
        interrupted(run_dir, interrupt_reason(exc))
    except BsslamError as exc:
        fail(exc)


def _run_log(header, config, folder, every, viewer: Optional[str], place: dict, resume: bool = False,
             parallel: bool = True) -> None:
    """The body of ``bsslam run`` for one log, fresh or resumed from the checkpoint in the
    folder ``folder()`` yields (put in ``place["run_dir"]`` at once, for the message of an
    interruption): run, write the outputs, print the summary; exits 130 on a partial
    result. ``parallel``: the reader and the front end in a second process when there
    are two cores or more."""
    from bsslam.helper_process import HelperProcess

    # its interpreter starts while this one imports the rest; after the frames it draws the map
    helper = HelperProcess(preload=("bsslam.outputs", "bsslam.viz.map_figure")) if parallel and (os.cpu_count() or 1) > 1 else None
    try:
        from bsslam.io import open_dataset
        from bsslam.io.checkpoint import Checkpointer, load_checkpoint
        from bsslam.io.reader_config import ReaderConfig
        from bsslam.io.trajectory_file import read_trajectory
        from bsslam.outputs import write_outputs
        from bsslam.pipeline import run_dataset
        from bsslam.viz.rerun_viewer import open_viewer

        opts = header.options
        log, steps = Path(header.log), opts["steps"]
        data = open_dataset(log, format=opts["fmt"], strict=opts["strict"], scan_topic=opts["scan_topic"],
                            odom_topic=opts["odom_topic"], reader_config=ReaderConfig(limits=config.input))
        ref = read_trajectory(opts["reference"]) if opts["reference"] else None
        header = dataclasses.replace(header, options={**opts, "checkpoint_every": str(every)})
        with _frozen_heap(), folder() as run_dir:
            place["run_dir"] = run_dir
            mapper, start = None, 0
            if resume:
                saved, mapper = load_checkpoint(run_dir)
                start = saved.next_frame
            checkpointer = Checkpointer(run_dir, every, header, start_frame=start)
            expected = getattr(data, "expected_frames", None)
            total = steps if expected is None else min(expected, steps or expected)
            with progress_bar(f"{log.name}", total, "scans") as update:
                result = run_dataset(data, config, steps=steps, progress=update, total=total,
                                     relocalize_progress=next_phase(update, f"{log.name}: relocalising"),
                                     viewer=open_viewer(viewer, run_dir) if viewer else None,
                                     mapper=mapper, start=start, checkpoint=checkpointer,
                                     prefetch=helper or False)
            extra = checkpointer.figures() | ({"resumed_at_frame": start} if resume else {})
            summary = write_outputs(result, run_dir, config, reference=ref, title=f"BS-SLAM: {log.name}",
                                    show_control_points=opts["show_control_points"], extra=extra, helper=helper)
            if summary.get("status") == "complete":
                checkpointer.remove()   # a complete run needs none; a partial one can still be resumed
        print_summary(summary, f"bsslam run {log}")
        if result.skipped.total:
            console.print(f"[yellow]skipped {result.skipped.total} input item(s):[/yellow] "
                          + ", ".join(f"{k}: {v}" for k, v in result.skipped.counts.items()))
            for ex in result.skipped.examples[:5]:
                console.print(f"  {ex}")
        if summary.get("status") == "interrupted" and checkpointer.path.exists():
            console.print(f"continue it from its last checkpoint: bsslam run --resume {escape(str(run_dir))}",
                          soft_wrap=True)
        exit_if_partial(summary, run_dir)
        console.print(f"results in [bold]{run_dir}[/bold]")
    finally:
        if helper is not None:
            helper.close()


def _reference_sigma(value: Optional[str]) -> Optional[tuple[float, float]]:
    """``--reference-sigma SXY,SPHI``: σ of x and y (m) and of the heading (deg), both ≥ 0."""
    if value is None:
        return None
    parts = value.split(",")
    try:
        sigma = tuple(float(p) for p in parts)
    except ValueError:
        sigma = ()
    if len(sigma) != 2 or not all(s >= 0 for s in sigma):  # also rejects nan, not inf
        raise typer.BadParameter(f"expected two numbers ≥ 0, 'SIGMA_XY_M,SIGMA_HEADING_DEG' (e.g. 0.03,0.5), "
                                 f"got {value!r}")
    if not all(s < float("inf") for s in sigma):
        raise typer.BadParameter(f"the reference σ must be finite, got {value!r}")
    return sigma


class NeesFrame(str, Enum):
    first_pose = "first-pose"
    aligned = "aligned"


@app.command()
def evaluate(
    estimate: Path = typer.Argument(..., help="Estimated trajectory (TUM or 't x y θ')."),
    reference: Path = typer.Argument(..., help="Reference trajectory (TUM or 't x y θ')."),
    relations: Optional[Path] = typer.Option(None, help="Kümmerle et al. relations file."),
    offset: float = typer.Option(0.0, help="Seconds to subtract from the relations' timestamps."),
    max_dt: float = typer.Option(0.05, help="Largest timestamp difference when matching poses (s)."),
    exact: bool = typer.Option(False, help="The reference is exact ground truth: also report NEES."),
    json_file: Optional[Path] = typer.Option(None, "--json", help="Also save the metrics as JSON to this file "
                                             "('-': print JSON instead of the table)."),
    plot: Optional[Path] = typer.Option(None, help="Also draw the aligned trajectories and the position error "
                                        "over time to this picture (.png, .svg or .pdf); with --covariance "
                                        "the NEES over time too."),
    covariance: Optional[Path] = typer.Option(None, help="The estimate's pose covariance CSV (a run's "
                                              "pose_covariance_online.csv with trajectory_online.tum): report "
                                              "NEES, the error taken in the frame of --nees-frame."),
    nees_frame: NeesFrame = typer.Option(NeesFrame.first_pose, help="first-pose: the reference moved onto the "
                                         "estimate's first pose, the frame a SLAM estimate's covariances refer "
                                         "to (its first pose has none); aligned: the ATE's best rigid fit, for "
                                         "estimates whose covariances are not relative to their first pose."),
    reference_sigma: Optional[str] = typer.Option(None, callback=_reference_sigma, metavar="SXY,SPHI",
                                                  help="The reference's own σ, x and y in m, heading in deg "
                                                  "(e.g. 0.03,0.5), added to the estimate's covariance for "
                                                  "NEES. Default 0,0."),
) -> None:
    """ATE, RPE, the relations metric and NEES of a trajectory against a reference."""
    import math

    from bsslam.eval.evaluate_files import evaluate_files, write_evaluation_plot, write_metrics_json

    sigma_xy_m, sigma_phi_deg = reference_sigma or (0.0, 0.0)
    nees_args = dict(covariance_path=covariance, reference_sigma_xy_m=sigma_xy_m,
                     reference_sigma_phi_rad=math.radians(sigma_phi_deg), nees_frame=nees_frame.value)
    try:
        if reference_sigma is not None and covariance is None:
            raise ConfigError("--reference-sigma is used by the NEES of --covariance: give --covariance FILE")
        metrics = evaluate_files(estimate, reference, relations_path=relations, offset=offset,
                                 max_dt=max_dt, exact_reference=exact, **nees_args)
        if json_file is not None and json_file != Path("-"):
            write_metrics_json(json_file, metrics)
        if plot is not None:
            write_evaluation_plot(estimate, reference, plot, max_dt=max_dt, exact_reference=exact, **nees_args)
    except BsslamError as exc:
        fail(exc)
    if json_file == Path("-"):
        typer.echo(json.dumps(metrics, indent=2))
    else:
        print_summary(metrics, f"{estimate} vs {reference}")


@app.command()
def bench(
    logs: Optional[List[str]] = typer.Argument(None, help="Logs: files, folders (searched for *.clf, *.carmen, "
                                               "*.bag and ROS 2 bags) and patterns such as 'data/*/*.clf'. "
                                               "Default: the logs in --data."),
    data: Optional[Path] = typer.Option(None, envvar="BSSLAM_DATA", help="Folder of logs (with *.gt.txt "
                                        "references) when no LOGS are given; default: $BSSLAM_DATA."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="YAML configuration (the same for every log)."),
    steps: Optional[int] = typer.Option(None, min=1, help="Only the first N scans of each log."),
    mode: Optional[str] = typer.Option(None, help="slam or localization (default: the configuration's)."),
    backend: Optional[str] = typer.Option(None, metavar="submaps|ekf", help=BACKEND_HELP),
    max_memory: Optional[float] = typer.Option(None, "--max-memory", metavar="MB", help=MAX_MEMORY_HELP),
    workers: Optional[int] = typer.Option(None, help=WORKERS_HELP),
    scheduler: Optional[str] = typer.Option(None, help=SCHEDULER_HELP),
    perturb: int = typer.Option(0, min=0, help="Run each log N times with every range moved by seeded "
                                "Gaussian noise (seeds 0…N−1, or from --first-seed) and once with float32 "
                                "ranges, and report "
                                "the spread of ATE: how much of a figure is the data, how much rounding."),
    perturb_sigma: float = typer.Option(0.001, min=0.0, help="σ of the --perturb noise (m)."),
    first_seed: int = typer.Option(0, "--first-seed", min=0, help="First seed of the --perturb runs "
                                   "(seeds K…K+N−1): another sample of runs than the usual one, e.g. "
                                   "--perturb 10 --first-seed 10 for a change the first ten do not settle."),
    json_file: Optional[Path] = typer.Option(None, "--json", metavar="FILE",
                                             help="Also write every run's figures (and with --perturb the "
                                             "spread) to FILE as JSON; '-' prints only the JSON."),
) -> None:
    """Accuracy and speed on several logs, one configuration for all, the logs in parallel."""
    from bsslam.bench import BenchFailure, bench_logs, bench_report, perturbations, stability
    from bsslam.io.atomic_file import atomic_write
    from bsslam.io.log_paths import find_logs

    try:
        if not logs and data is None:
            raise ConfigError("name the logs (bsslam bench LOGS...) or their folder (--data DIR, or the "
                              "BSSLAM_DATA environment variable)")
        found = find_logs(logs or [data])
        config = _overridden(_load_config(config_file), mode, backend, max_memory)
        if json_file is not None and json_file != Path("-"):
            # before the runs, which may take an hour: a path that cannot be written
            if json_file.is_dir() or not json_file.resolve().parent.is_dir():
                raise ConfigError(f"--json {json_file}: not a file in an existing folder")
        if first_seed and not perturb:
            raise ConfigError("--first-seed chooses the seeds of the --perturb runs: give --perturb N too")
        runs = perturbations(perturb, perturb_sigma, first_seed) if perturb else []
        with progress_bar(f"bench: {len(found)} log(s)", len(found) * max(len(runs), 1), "runs") as update:
            rows = bench_logs(found, config, steps=steps, workers=workers, scheduler=scheduler, progress=update,
                              perturb=runs)
    except BsslamError as exc:
        fail(exc)
    if json_file is not None:
        text = json.dumps(bench_report(rows, perturb_sigma if perturb else None), indent=2) + "\n"
        if json_file == Path("-"):
            typer.echo(text, nl=False)
            return
        try:
            with atomic_write(json_file) as fh:
                fh.write(text)
        except BsslamError as exc:
            fail(exc)
    # The log and its input variant are the row's key: never wrapped, whatever the terminal.
    table = Table(Column("log", no_wrap=True), Column("input", no_wrap=True), "scans", "wall s", "ms/scan",
                  "splines", "max state", "submaps", "loops", "peak RSS MB", "ATE m", "online ATE m", "odometry ATE m", "front end ATE m",
                  "online NEES: median, outside 95 % (aligned)", "relations (Intel)",
                  title=f"bsslam bench ({config.mode}, backend {config.backend})")
    for row in rows:
        if isinstance(row, BenchFailure):
            console.print(f"[red]{escape(row.log)}: {escape(row.message)}[/red]", soft_wrap=True)
            continue
        table.add_row(row.log, row.variant, str(row.scans) + (" (stopped)" if row.stopped else ""),
                      f"{row.wall_s:.1f}", f"{row.ms_per_scan:.1f}", str(row.splines), str(row.state_size),
                      str(row.submaps), str(row.loop_closures), f"{row.peak_rss_mb:.0f}", f"{row.ate_m:.3f}", f"{row.online_ate_m:.3f}", f"{row.odometry_ate_m:.3f}", f"{row.frontend_ate_m:.3f}",
                      f"{row.nees_median:.1f}, {100 * row.nees_outside_95:.0f} % ({100 * row.nees_outside_95_aligned:.0f} %)",
                      row.relations)
    Console(width=max(Console().width, 200)).print(table)
    if perturb:
        spread = Table("log", "runs", "median ATE m", "min", "max", "float32", "(max−min)/median",
                       "worst/median", "online NEES: median", "outside 95 %",
                       title=f"ATE over {perturb} runs (seeds {first_seed}…{first_seed + perturb - 1}) with "
                       f"{1000 * perturb_sigma:g} mm range noise "
                       "(target: spread ≤ 0.2, worst ≤ 1.5 × median); the online covariance over them "
                       "and float32, medians of each run's (calibrated: 2.4, 5 %)")
        for st in stability(rows):
            spread.add_row(st.log, str(st.runs), f"{st.median_m:.3f}", f"{st.min_m:.3f}", f"{st.max_m:.3f}",
                           f"{st.float32_m:.3f}", f"{st.spread:.2f}", f"{st.worst_ratio:.2f}",
                           f"{st.nees_median:.1f}", f"{100 * st.outside_95:.0f} %")
        Console(width=max(Console().width, 150)).print(spread)
    ran = [row for row in rows if not isinstance(row, BenchFailure)]
    for row in ran:
        if row.stopped:
            console.print(f"[yellow]{escape(row.log)}: {escape(row.stopped)}[/yellow]", soft_wrap=True)
    if ran:
        console.print(f"peak memory (max RSS) of the processes that ran the logs: "
                      f"{max(row.peak_rss_mb for row in ran):.0f} MB")


@app.command("config")
def show_config(config_file: Optional[Path] = typer.Option(None, "--config", help="Print this file's "
                                                           "configuration instead, defaults filled in.")) -> None:
    """Print the default configuration as YAML: a starting point for --config FILE."""
    from bsslam.io.config_file import write_config

    try:
        write_config(sys.stdout, _load_config(config_file))
    except BsslamError as exc:
        fail(exc)


class TrajectoryFormat(str, Enum):
    tum = "tum"
    xytheta = "xytheta"


@app.command()
def convert(
    source: Path = typer.Argument(..., help="Trajectory file: TUM or 'stamp x y θ' (told by its column count)."),
    target: Path = typer.Argument(..., help="File to write."),
    to: Optional[TrajectoryFormat] = typer.Option(None, help="Format to write (default: tum for a *.tum "
                                                  "TARGET, else xytheta, i.e. 'stamp x y θ')."),
) -> None:
    """Convert a trajectory between TUM and 'stamp x y θ'."""
    from bsslam.io.trajectory_file import format_from_name, read_trajectory, write_trajectory

    fmt = to.value if to is not None else format_from_name(target)
    try:
        trajectory = read_trajectory(source)
        write_trajectory(target, trajectory, fmt)
    except BsslamError as exc:
        fail(exc)
    console.print(f"wrote {len(trajectory)} poses to [bold]{escape(str(target))}[/bold] ({fmt})")


# --------------------------------------------------------------------------------------
def _fit_experiment(kind: str, runs: int, seed: int, resolution_deg: float, sigma: float, out: Path) -> None:
    """Shared body of fit-knots and fit-order: run, write CSV + PNG, print the table."""
    from bsslam.experiments import fit

    experiment, writer, column, title = {
        "knots": (fit.fit_knots_experiment, fit.write_fit_knots, "knot spacing (m)", "Fit error vs knot spacing (cubic)"),
        "order": (fit.fit_order_experiment, fit.write_fit_order, "order", "Fit error vs order (knot spacing 2.92 m)"),
    }[kind]
    settings = {"experiment": f"fit-{kind}", "runs": runs, "seed": seed, "resolution_deg": resolution_deg, "sigma_m": sigma}
    with experiment_folder(out, settings) as run_dir:
        with progress_bar(f"fit vs {kind}", None, "runs") as update:
            results = experiment(runs=runs, seed=seed, resolution_deg=resolution_deg, sigma_m=sigma, progress=update)
        writer(results, run_dir, seed=seed, resolution_deg=resolution_deg, sigma_m=sigma)
    table = Table(column, "MSE (m²)", title=title)
    for value, mse in results:
        table.add_row(f"{value:.3g}", f"{mse:.3e}")
    Console().print(table)
    console.print(f"results in [bold]{run_dir}[/bold]")


@experiment_app.command("fit-knots")
def fit_knots(runs: int = typer.Option(50, help="Monte Carlo runs per spacing."),
              seed: int = typer.Option(0),
              resolution_deg: float = typer.Option(1.0, help="Angle between beams (deg)."),
              sigma: float = typer.Option(0.005, help="Range noise σ (m)."),
              out: Path = typer.Option(Path("results/fit-knots"), help=OUT_HELP)) -> None:
    """Paper Fig. 2: mean squared range error of a cubic fit vs. knot spacing."""
    _fit_experiment("knots", runs, seed, resolution_deg, sigma, out)


@experiment_app.command("fit-order")
def fit_order(runs: int = typer.Option(50, help="Monte Carlo runs per order."),
              seed: int = typer.Option(0),
              resolution_deg: float = typer.Option(1.0, help="Angle between beams (deg)."),
              sigma: float = typer.Option(0.005, help="Range noise σ (m)."),
              out: Path = typer.Option(Path("results/fit-order"), help=OUT_HELP)) -> None:
    """Paper Fig. 3: mean squared range error of linear, quadratic and cubic fits."""
    _fit_experiment("order", runs, seed, resolution_deg, sigma, out)


class Variant(str, Enum):
    no_extension = "no-extension"
    inflated_r = "inflated-r"
    extension = "extension"


class Estimator(str, Enum):
    ekf = "ekf"
    oc_ekf = "oc-ekf"
    invariant = "invariant"


ESTIMATOR_HELP = ("ekf: the paper's filter; oc-ekf: the observability-constrained EKF (global translation "
                  "and rotation stay unobservable in its linearisations); invariant: the EKF in invariant "
                  "error coordinates, where they are unobservable exactly.")


@experiment_app.command("consistency")
def consistency(variant: Variant = typer.Option(..., help="Which filter variant."),
                runs: int = typer.Option(50, help="Monte Carlo runs."), seed: int = typer.Option(0),
                world: str = typer.Option("rounded-room", help="Simulated world."),
                steps: Optional[int] = typer.Option(None, min=1, help="Steps per run (default: the double loop)."),
                workers: Optional[int] = typer.Option(None, help=WORKERS_HELP),
                scheduler: Optional[str] = typer.Option(None, help=SCHEDULER_HELP),
                estimator: Optional[Estimator] = typer.Option(
                    None, help=ESTIMATOR_HELP + " [default: the --config file's, else ekf]", show_default=False),
                significant_bends: Optional[bool] = typer.Option(
                    None, help="What a map spline says along itself limited to its significant bend, and what "
                    "a scan's walls say along their common direction to their significant angles "
                    "(observation.significant_bends_only and significant_wall_angles); off: the paper's update. "
                    "[default: the --config file's, else off]", show_default=False),
                config_file: Optional[Path] = typer.Option(
                    None, "--config", help="YAML configuration the variant starts from (e.g. observation "
                    "noise); the variant's own settings and the simulator's noise take precedence."),
                range_noise_scale: float = typer.Option(
                    1.0, min=0.0, help="Multiply the simulated range noise σ (5 mm) by this; the filter is "
                    "told the same σ."),
                translation_noise_scale: float = typer.Option(
                    1.0, min=0.0, help="Multiply the simulated odometry's translation σ (1 mm + 10 % of the "
                    "step) by this; the filter is told the same."),
                heading_noise_scale: float = typer.Option(
                    1.0, min=0.0, help="Multiply the simulated odometry's heading σ (0.02 rad + 10 % of the "
                    "turn) by this; the filter is told the same."),
                out: Path = typer.Option(Path("results/consistency"), help=OUT_HELP)) -> None:
    """Paper Figs. 10/12: average pose NEES over Monte Carlo runs with the 95% χ² band.

    A consistent linear filter stays in its band whatever the noise: with the noise scales
    you can see which noise's non-linear effects take a filter out of it."""
    import dataclasses

    from bsslam.experiments.consistency import consistency_experiment, paper_filter, scaled_noise, write_consistency

    try:
        base = _load_config(config_file) if config_file else paper_filter(_load_config(None))
    except BsslamError as exc:
        fail(exc)
    if estimator is not None:
        base = base.replace(estimator=estimator.value)
    if significant_bends is not None:
        base = base.replace(observation=dataclasses.replace(base.observation, significant_bends_only=significant_bends,
                                                            significant_wall_angles=significant_bends))
    try:
        sim = scaled_noise(range_scale=range_noise_scale, translation_scale=translation_noise_scale,
                           heading_scale=heading_noise_scale)
    except BsslamError as exc:
        fail(exc)
    settings = {"experiment": "consistency", "variant": variant.value, "runs": runs, "seed": seed, "world": world,
                "steps": steps, "estimator": base.estimator,
                "significant_bends": base.observation.significant_bends_only,
                "significant_wall_angles": base.observation.significant_wall_angles,
                "config": str(config_file) if config_file else None,
                "noise_scales": {"range": range_noise_scale, "translation": translation_noise_scale,
                                 "heading": heading_noise_scale}}
    with experiment_folder(out, settings) as run_dir:
        with progress_bar(f"consistency ({variant.value})", runs, "runs") as update:
            res = consistency_experiment(variant.value, runs=runs, seed=seed, world=world, steps=steps,
                                         workers=workers, scheduler=scheduler, progress=update, base=base, sim=sim)
        write_consistency(res, run_dir, ", ".join(f"{k} noise × {v:g}"
                                                  for k, v in settings["noise_scales"].items() if v != 1.0))
        exit_step = res.first_exit()
        z = res.shared_bias()
        mean_nees = float(res.mean_nees.mean())
        settings["results"] = {   # in summary.json too
            "band": [round(res.lower, 4), round(res.upper, 4)],
            "fraction_inside_band": round(res.fraction_inside(), 4), "first_exit_step": exit_step,
            "mean_nees": round(mean_nees, 4),
            "rms_mean_error_z": [round(float(v), 2) for v in z],
        }
    print_summary({
        "variant": res.variant, "world": res.world, "runs": runs, "steps": int(res.mean_nees.size),
        "band": f"[{res.lower:.2f}, {res.upper:.2f}]",
        "fraction of steps inside band": f"{res.fraction_inside():.2f}",
        "leaves band (optimistic) at step": exit_step if exit_step is not None else "never",
        "mean NEES over the steps": f"{mean_nees:.2f}",
        "mean error in standard errors, RMS over the steps (x, y, φ; 1 if no bias)":
            f"{z[0]:.1f}, {z[1]:.1f}, {z[2]:.1f}",
    }, "NEES consistency")
    console.print(f"results in [bold]{run_dir}[/bold]")


@experiment_app.command("heading-gain")
def heading_gain(runs: int = typer.Option(50, help="Monte Carlo runs per initial σ."),
                 updates: int = typer.Option(30, help="Scans per run."), seed: int = typer.Option(0),
                 workers: Optional[int] = typer.Option(None, help=WORKERS_HELP),
                 scheduler: Optional[str] = typer.Option(None, help=SCHEDULER_HELP),
                 estimator: Estimator = typer.Option(Estimator.ekf, help=ESTIMATOR_HELP),
                 out: Path = typer.Option(Path("results/heading-gain"), help=OUT_HELP)) -> None:
    """Paper Fig. 11: estimated heading σ of a stationary robot over updates."""
    from bsslam.experiments.consistency import paper_filter
    from bsslam.experiments.heading import DEFAULT_SIGMAS_RAD, heading_gain_experiment, write_heading_gain

    from bsslam.config import SLAMConfig

    base = paper_filter(SLAMConfig()).replace(estimator=estimator.value)
    settings = {"experiment": "heading-gain", "runs": runs, "updates": updates, "seed": seed,
                "estimator": base.estimator, "significant_bends": base.observation.significant_bends_only}
    with experiment_folder(out, settings) as run_dir:
        with progress_bar("heading gain", runs * len(DEFAULT_SIGMAS_RAD), "runs") as update:
            res = heading_gain_experiment(runs=runs, updates=updates, seed=seed, workers=workers,
                                          scheduler=scheduler, progress=update, base=base)
        write_heading_gain(res, run_dir)
    table = Table("σ₀ (rad)", "σ_φ after 1 update", f"σ_φ after {updates}", title="Heading information gain")
    for s0, sig in res.items():
        table.add_row(f"{s0:g}", f"{sig[0]:.4g}", f"{sig[-1]:.4g}")
    Console().print(table)
    console.print(f"results in [bold]{run_dir}[/bold]")


if __name__ == "__main__":  # pragma: no cover
    app()
