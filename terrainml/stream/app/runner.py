"""The serving loop behind ``terrainml predict``: source -> Predictor -> sinks.

Everything the user should see besides the messages (start-up line, warnings, the end-of-stream
summary) goes to stderr; with ``--sink stdout`` stdout carries only JSON lines.
"""

from __future__ import annotations

import gc
import logging
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from terrainml.stream.tick.classify import ModelLoadError
from terrainml.stream.tick.inputs import InputWatch
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.app.options import ServeOptions
from terrainml.stream.app.recorder import UnknownGroundRecorder
from terrainml.stream.tick.sample import InvalidSample
from terrainml.stream.transports.sinks import GuardedSink, SinkError, open_sink
from terrainml.stream.transports.sources import SourceCounters, SourceError, open_source

log = logging.getLogger("terrainml.stream")

#: exit code of ``terrainml predict`` when a live source ended on ``--idle-timeout-s``
EXIT_IDLE = 3


def serve(predictor: Predictor, samples: Iterable[Any], sinks: Sequence[Any],
          on_message: Any = None, watch: InputWatch | None = None) -> int:
    """Feed every sample to the predictor and every message to every sink; return #messages.

    Each sink is handed the message and the tick's :class:`~terrainml.stream.tick.sample.Sample`
    (``sink.send(msg, sample)``: the ROS 2 sink's stamps and odometry, the recorder's rows). A
    sample the predictor refuses (:class:`~terrainml.stream.tick.sample.InvalidSample`, counted in
    ``predictor.counters``) is skipped; serving goes on. ``watch``: the source's topics; once it
    knows the sensor groups the source maps (a live topic map's, or those a log has), the predictor is told
    (:meth:`Predictor.set_mapped_groups`) before the first tick.
    """
    n = 0
    told = False
    for raw in samples:
        if not told and watch is not None and watch.mapped_groups is not None:
            predictor.set_mapped_groups(watch.mapped_groups)
            predictor.health.invalid_hint = watch.group_invalid
            told = True
        try:
            sample = predictor.accept(raw)
        except InvalidSample as exc:
            n_bad = predictor.counters.bad_time + predictor.counters.not_a_sample
            if n_bad <= 3 or n_bad % 1000 == 0:
                log.warning("sample skipped (%d so far): %s", n_bad, exc)
            continue
        msg = predictor.step(sample)
        if msg is None:
            continue
        for s in sinks:
            s.send(msg, sample)
        if on_message is not None:
            on_message(msg)
        n += 1
    return n


class _CurrentStderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at emit time.

    A second run in one process (a test harness, a notebook, a caller that redirects stderr)
    must not write to, or flush, the stream of the first run, which may be closed by now;
    this is what ``logging.lastResort`` does too.
    """

    @property
    def stream(self):  # type: ignore[override]
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:
        pass


def _setup_logging(verbose: bool) -> None:
    root = logging.getLogger("terrainml")
    if not any(isinstance(h, _CurrentStderrHandler) for h in root.handlers):
        h = _CurrentStderrHandler()
        h.setFormatter(logging.Formatter("terrainml predict: %(levelname)s %(message)s"))
        root.addHandler(h)
    root.setLevel(logging.INFO if verbose else logging.WARNING)


def run_predict(options: ServeOptions) -> int:
    """Run ``terrainml predict``; return the process exit code (0 ok, 2 unusable input,
    :data:`EXIT_IDLE` (3) a live source silent for ``idle_timeout_s``: the line before says which
    topics and how long).

    ``options`` (:class:`~terrainml.stream.app.options.ServeOptions`) is resolved by the caller
    (the CLI). A model not signed by one of ``options.trusted_keys`` (when any) is refused (exit 2,
    the message names the folder and the reason) before anything is served. With
    ``options.record_unknown`` every stretch served ``unknown_terrain`` is written there as a run
    for labelling (:class:`~terrainml.stream.app.recorder.UnknownGroundRecorder`); a folder that
    cannot be created or an unknown format is refused (exit 2) before serving, a failed write
    later is only counted.
    """
    console = Console(stderr=True, soft_wrap=True)
    _setup_logging(options.verbose)
    model = options.model
    try:
        predictor = Predictor.from_model_dir(model, robot=options.robot, config=options.config,
                                             trusted_keys=options.trusted_keys or None)
    except (ModelLoadError, FileNotFoundError, ValueError) as exc:
        console.print(f"[red]error:[/] model {model}: {exc}")
        return 2
    recorder = _open_recorder(options, predictor, console)
    if recorder is False:
        predictor.close()
        return 2
    watch = InputWatch()   # the source's topics and groups, for the ROS 2 sink's /diagnostics
    counters = SourceCounters()
    opened = _open_sinks(options.sinks, predictor, watch, console)
    if opened is None:
        return 2
    try:
        samples = open_source(options.source, options.source_options, robot=predictor.robot, counters=counters,
                              ready=_ready_line(options, console), watch=watch)
    except SourceError as exc:
        console.print(f"[red]error:[/] {exc}")
        for s in opened:
            s.close()
        return 2
    # everything loaded so far (model, libraries) is long-lived: keep it out of the garbage
    # collector's full passes, which otherwise stall a tick for tens of ms now and then
    gc.collect()
    gc.freeze()
    t0 = time.perf_counter()
    log_name = None if options.source_options.realtime or not _is_log(options.source) else Path(options.source).name
    code = _serve_until_done(predictor, samples, opened + ([recorder] if recorder is not None else []), console,
                             progress=log_name, watch=watch)
    if code == 0 and counters.idle is not None:
        code = EXIT_IDLE
    _print_summary(console, predictor, opened, counters, options.source, time.perf_counter() - t0)
    if recorder is not None:
        console.print(f"terrainml predict: {recorder.summary()}", highlight=False)
    return code


def _open_recorder(options: ServeOptions, predictor: Predictor, console: Console) -> Any:
    """The ``--record-unknown`` recorder, None without one, False when it cannot be opened (said)."""
    folder = options.record_unknown
    if folder is None:
        return None
    try:
        recorder = UnknownGroundRecorder(
            folder, n_wheels=predictor.n, class_names=predictor.class_names, model=str(options.model),
            distance=lambda: predictor.odometer_m, fmt=options.record_format, robot=predictor.robot)
    except (OSError, ValueError) as exc:
        what = "cannot create the folder" if isinstance(exc, OSError) else "--record-format"
        console.print(f"[red]error:[/] --record-unknown {folder}: {what} ({exc})", highlight=False)
        return False
    if getattr(predictor.classifier, "novelty", None) is None:
        console.print(f"[yellow]warning:[/] --record-unknown: model {options.model} has no novelty scorer (a CNN, "
                      "or a folder without one) or is served --closed-set: it never serves unknown_terrain, so "
                      "nothing will be recorded",
                      highlight=False)
    return recorder


def _open_sinks(specs: Sequence[str], predictor: Predictor, watch: InputWatch,
                console: Console) -> list[GuardedSink] | None:
    """Every ``--sink``, guarded; None when one cannot be opened (said; those opened are closed)."""
    opened: list[GuardedSink] = []
    try:
        for spec in specs:
            opened.append(open_sink(spec, n_wheels=predictor.n, n_classes=len(predictor.class_names),
                                    class_names=predictor.class_names, robot=predictor.robot,
                                    sensors=predictor.sensors, watch=watch))
    except SinkError as exc:
        console.print(f"[red]error:[/] {exc}")
        for s in opened:
            s.close()
        return None
    return opened


def _ready_line(options: ServeOptions, console: Console) -> Callable[[Any], None]:
    """What the source calls once it listens: the start-up line (stderr)."""
    def ready(addr: Any) -> None:
        where = f"udp://{addr[0]}:{addr[1]}" if addr else options.source
        console.print(f"terrainml predict: ready, reading {where}, serving to {', '.join(options.sinks)}",
                      highlight=False)
    return ready


def _is_log(source: str) -> bool:
    return not (source.strip() == "-" or source.strip().startswith(("udp", "ros2")))


def _serve_until_done(predictor: Predictor, samples: Iterable[dict], opened: list[Any],
                      console: Console, progress: str | None, watch: InputWatch | None = None) -> int:
    """:func:`serve` until the source ends, SIGTERM or Ctrl-C; close everything; the exit code.

    ``progress``: the log's name, for a spinner counting ticks (a log replayed at full speed).
    """
    def _term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    code = 0
    try:
        if progress is not None:
            with Progress(SpinnerColumn(), TextColumn("replaying {task.description}: "
                                                      "{task.completed:,.0f} ticks"),
                          TimeElapsedColumn(), console=console, transient=True) as bar:
                task = bar.add_task(progress, total=None)
                serve(predictor, samples, opened,
                      on_message=lambda m: bar.advance(task, 100) if m.seq % 100 == 99 else None, watch=watch)
        else:
            serve(predictor, samples, opened, watch=watch)
    except KeyboardInterrupt:
        log.info("interrupted")
    except SourceError as exc:
        console.print(f"[red]error:[/] {exc}")
        code = 2
    finally:
        signal.signal(signal.SIGTERM, old)
        predictor.close()
        for s in opened:
            s.close()
    return code


def _print_summary(console: Console, predictor: Predictor, opened: list[GuardedSink],
                   counters: SourceCounters, source: str, dt: float) -> None:
    """The end-of-stream summary line (stderr), and the source's damage when it had any."""
    st = predictor.stats()
    sink_err = {s.name: s.errors for s in opened if s.errors}
    reasons = ", ".join(f"{k} {v}" for k, v in sorted(counters.malformed_by_reason.items()))
    console.print(
        f"terrainml predict: {st['emitted']} messages in {dt:.1f} s; dropped: "
        f"{st['duplicate']} duplicate, {st['out_of_order']} out-of-order, {st['bad_time']} bad t_s, "
        f"{st['not_a_sample']} not a sample; clock: {st['clock_jump']} clock-jump ticks, "
        f"{st['reanchors']} re-anchors; malformed input: {counters.malformed}"
        f"{f' ({reasons})' if reasons else ''}; classifications: {st['classifications']} "
        f"({st['classifier_errors']} errors); sink errors: {sink_err or 0}",
        highlight=False)
    if st["unsteady_windows"]:
        console.print(f"terrainml predict: {rejection_text(st)}", highlight=False)
    if st.get("unknown_stretches"):  # ground unlike the model's training windows
        console.print(f"terrainml predict: unknown ground: {st['unknown_stretches']} stretch(es) of windows "
                      "unlike the model's training windows, served the safe cap (unknown_terrain)",
                      highlight=False)
    if counters.damage is not None and counters.damage.any:
        console.print(f"terrainml predict: source {source}: {counters.damage.text}", highlight=False)


def rejection_text(stats: dict[str, Any]) -> str:
    """The summary's line of rejected windows: per window rule, and the invalid channels."""
    rules = ", ".join(f"{r} {n}" for r, n in sorted(stats["rejections"].items(), key=lambda kv: -kv[1]))
    chans = stats.get("rejected_channels") or {}
    where = (f"; invalid channels: {', '.join(f'{c} {n}' for c, n in sorted(chans.items(), key=lambda kv: -kv[1]))}"
             if chans else "")
    return (f"windows rejected: {stats['unsteady_windows']} (by rule, a window may fail several: "
            f"{rules or 'none named'}){where}")
