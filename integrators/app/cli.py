"""Command line: ``python -m integrators render|list``.

    render SCENE.xml [-D name=value ...] [--spp N | --time S] [--seed S] [-o OUT.exr]
                     [--variant V] [--checkpoint SECONDS] [--quiet]
                     [--workers N | --scheduler ADDRESS]
        Renders with the scene's own integrator, progressively in passes (see
        integrators.app.progressive), and writes OUT.exr (RGB + variance layer, the run record
        in the header: integrators.app.record) plus OUT.png (sRGB preview), replaced together.
        -D sets the XML ``$name`` defaults, as Mitsuba's own command line does.  Ctrl-C /
        SIGTERM after the first pass finish the pass in flight, write what was accumulated and
        exit with 130 / 143 (before it: exit at once, nothing written).  --workers N renders
        on a Dask LocalCluster of N processes on this machine, --scheduler on an existing Dask
        cluster (integrators.app.distributed: tasks of disjoint seed ranges, merged exactly);
        without either, the render runs in this process.
    merge A.exr B.exr ... -o OUT.exr
        Sample-weighted mean of independent runs of the same scene and integrator; refuses
        runs whose records differ (scene content, integrator, parameters, variant, defines) or
        whose seed ranges overlap.
    list
        Every registered plugin with its parameters, defaults and allowed values (the same specs
        the plugins validate with).

Errors are one line on stderr (``--debug`` shows the traceback).  Exit status: 0 done, 1 an
unexpected internal error, 2 a usage, scene, parameter or file error, 130 SIGINT, 143 SIGTERM
(integrators.app.interrupt: at start-up nothing is written; mid-render the passes finished so
far are; a write in progress is always finished first).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import interrupt

MAX_SEED = (1 << 32) - 1      # = progressive.MAX_SEED (not imported: that pulls in Mitsuba)
MAX_SPP = (1 << 32) - 1       # = progressive.MAX_SPP
MAX_WORKERS = 4096            # worker processes of --workers on one machine


class UserError(Exception):
    """An error that is the user's to fix: printed as one line, no traceback."""


class _Parser(argparse.ArgumentParser):
    """argparse with every usage error as one line (a UserError), not the usage block."""

    def error(self, message):
        raise UserError(_usage_error(self.prog, message))


def _usage_error(prog: str, message: str, flags=()) -> str:
    message = " ".join(str(message).split())
    cmd = prog.split()[-1] if prog.split()[-1] in ("render", "merge", "list") else ""
    helpline = f"see 'python -m integrators {cmd + ' ' if cmd else ''}--help'"
    m = re.match(r"argument ([^:]+): (.*)$", message)
    if m:
        flag, rest = m.group(1).split("/")[-1], m.group(2)
        if rest.startswith(flag):            # our converters name the flag themselves
            return rest
        if rest.startswith("expected one argument"):
            return f"{flag} needs a value; {helpline}"
        if flag == "command" or "invalid choice" in rest:
            c = re.search(r"invalid choice: '?([^' ]*)'?", rest)
            return f"unknown command {c.group(1)!r} (commands: render, merge, list)" if c \
                else f"{rest}; {helpline}"
        return f"{flag}: {rest}; {helpline}"
    m = re.match(r"unrecognized arguments: (.*)$", message)
    if m:
        words = m.group(1).split()
        opt = next((w for w in words if w.startswith("-")), None)
        if opt:
            opt = opt.split("=")[0]
            near = sorted(f for f in flags if f.startswith(opt) and f != opt)
            also = f" (options are not abbreviated: {' or '.join(near)}?)" if near else ""
            return f"unknown option {opt}{also}; {helpline}"
        return f"unexpected argument {words[0]!r}; {helpline}"
    m = re.match(r"the following arguments are required: (.*)$", message)
    if m:
        names = m.group(1)
        if names in ("command", "{render,merge,list}"):
            return "missing command: render, merge or list; see 'python -m integrators --help'"
        return f"{cmd + ': ' if cmd else ''}missing {names}; {helpline}"
    return f"{message}; {helpline}"


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m integrators", description="Mitsuba 3 sampling-strategy integrators",
                allow_abbrev=False)
    p.add_argument("--debug", action="store_true", help="show Python tracebacks")
    sub = p.add_subparsers(dest="command", required=True, metavar="{render,merge,list}")
    r = sub.add_parser("render", help="render a Mitsuba XML scene", allow_abbrev=False)
    r.add_argument("scene", help="scene XML file")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="set an XML $NAME default (repeatable)")
    r.add_argument("--spp", type=_int_arg("--spp", 1, MAX_SPP),
                   help="samples per pixel (default: scene's)")
    r.add_argument("--time", type=_seconds_arg("--time"), metavar="SECONDS",
                   help="time budget: stop after the pass that crosses it")
    r.add_argument("--checkpoint", type=_seconds_arg("--checkpoint"), metavar="SECONDS",
                   help="write the running estimate every SECONDS")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--seed", type=_int_arg("--seed", 0, MAX_SEED), default=0,
                   help="sampler seed of the first pass (one seed per pass)")
    r.add_argument("-o", "--output", help="output EXR (default: SCENE name in the current dir)")
    r.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb)")
    r.add_argument("--workers", type=_int_arg("--workers", 1, MAX_WORKERS), metavar="N",
                   help="render on a Dask LocalCluster of N worker processes on this machine")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on the Dask cluster of this scheduler (e.g. tcp://HOST:8786)")
    r.add_argument("--debug", action="store_true", help="show Python tracebacks")
    m = sub.add_parser("merge", help="merge independent renders of one scene", allow_abbrev=False)
    m.add_argument("inputs", nargs="+", help="EXR files written by render")
    m.add_argument("-o", "--output", required=True, help="merged EXR")
    m.add_argument("--debug", action="store_true", help="show Python tracebacks")
    ls = sub.add_parser("list", help="list plugins and their parameters", allow_abbrev=False)
    ls.add_argument("--markdown", action="store_true",
                    help="parameter tables in Markdown (as in the README)")
    ls.add_argument("--debug", action="store_true", help=argparse.SUPPRESS)
    return p


def _int_arg(flag, minimum, maximum):
    def conv(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} = {s!r} is not an integer") from None
        if v < minimum:
            word = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
            raise argparse.ArgumentTypeError(f"{flag} = {v} must be {word}")
        if v > maximum:
            raise argparse.ArgumentTypeError(f"{flag} = {v} is too large: at most {maximum}")
        return v
    return conv


def _seconds_arg(flag):
    def conv(s):
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} = {s!r} is not a number of seconds") from None
        if not v > 0 or v != v or v == float("inf"):
            raise argparse.ArgumentTypeError(f"{flag} = {s} must be a positive number of seconds")
        return v
    return conv


def _defines(items):
    out = {}
    for item in items:
        if "=" not in item or not item.split("=", 1)[0]:
            raise UserError(f"-D {item!r}: expected NAME=VALUE")
        k, v = item.split("=", 1)
        out[k] = v
    return out


def _clean(msg) -> str:
    """Mitsuba error text without its source-file tags, on one line."""
    msg = re.sub(r"\[[\w./-]+\.cpp:\d+\]\s*", "", str(msg))
    if "Traceback (most recent call last):" in msg:
        # a Python plugin raised: keep Mitsuba's location and the exception's own message
        head, tail = msg.split("Traceback (most recent call last):", 1)
        lines = [ln for ln in tail.strip().splitlines() if ln.strip()]
        last = lines[-1].strip() if lines else ""
        msg = head + re.sub(r"^[\w.]*(Error|Exception|Warning):\s*", "", last)
    lines = [ln.strip() for ln in msg.strip().splitlines() if ln.strip()]
    return " ".join(lines)


def _root(e: BaseException) -> BaseException:
    """The exception that caused ``e``: Mitsuba and Dr.Jit wrap a plugin's exception (e.g.
    "drjit.custom(...): error while performing a custom differentiable operation. (see
    above)") and keep the real one in ``__cause__``."""
    seen = set()
    while id(e) not in seen:
        seen.add(id(e))
        nxt = e.__cause__
        if nxt is None and "(see above)" in str(e):
            nxt = e.__context__
        if nxt is None:
            break
        e = nxt
    return e


def _check_output(out: Path) -> None:
    """Refuse, before rendering, an output that cannot be written."""
    if out.suffix.lower() != ".exr":
        raise UserError(f"output {out}: the file name must end in .exr")
    for p in (out, out.with_suffix(".png")):
        if p.is_dir():
            raise UserError(f"output {p} is a directory")
    d = out.parent if str(out.parent) else Path(".")
    while not d.exists() and d != d.parent:
        d = d.parent
    if not d.is_dir():
        raise UserError(f"cannot write {out}: {d} is not a directory")
    if not os.access(d, os.W_OK | os.X_OK):
        raise UserError(f"cannot write {out}: directory {d} is not writable")


def _set_variant(name: str) -> None:
    import drjit as dr
    import mitsuba as mi

    import integrators
    if name.startswith("cuda_") and name in mi.variants() and \
            not dr.has_backend(dr.JitBackend.CUDA):
        raise UserError(f"variant {name!r} needs an NVIDIA GPU with a CUDA driver, and there is "
                        f"none here; use an llvm_ or scalar_ variant (default "
                        f"{integrators.DEFAULT_VARIANT})")
    try:
        integrators.set_variant(name)
    except (ValueError, RuntimeError, ImportError, AttributeError) as e:
        raise UserError(f"variant {name!r} cannot be used here: {_clean(e)}") from None


def _check_scene(scene, scene_path) -> None:
    """check_scene (integrators.plugins.base) for a scene rendered by one of our integrators:
    media, NaN/Inf/negative emitters, NaN BSDF values are one line before rendering."""
    from .. import registry
    integ = scene.integrator()
    name = getattr(integ, "NAME", None)
    if not name or name not in registry.plugins():
        return
    try:
        from ..plugins.base import check_scene
    except ImportError:
        return
    try:
        notes = check_scene(scene, name, bool(getattr(integ, "HANDLES_MEDIA", False)))
    except ValueError as e:
        raise UserError(f"{scene_path}: {_clean(e)}") from None
    for note in notes or ():
        print(f"warning: {_clean(note)}", file=sys.stderr)


def _render_failure(e: BaseException, where) -> BaseException:
    """The one-line error for an exception raised while rendering (or its own root cause when
    that is an internal error: exit status 1)."""
    root = _root(e)
    if isinstance(root, MemoryError):
        return UserError(f"{where}: out of memory while rendering; render a smaller film or "
                         "fewer samples per pass")
    if isinstance(root, (ValueError, RuntimeError)):
        return UserError(f"{where}: {_clean(root)}")
    return root


def cmd_render(args, ints) -> int:
    import mitsuba as mi

    import integrators  # noqa: F401

    from . import progressive
    ints.before = " before the first pass finished"
    scene_path = Path(args.scene)
    if not scene_path.exists():
        raise UserError(f"scene file not found: {scene_path}")
    if scene_path.is_dir():
        raise UserError(f"scene {scene_path} is a directory, not a scene file")
    if args.variant:
        _set_variant(args.variant)
    out = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    _check_output(out)
    defines = _defines(args.defines)
    distributed = args.workers is not None or args.scheduler is not None
    if args.workers is not None and args.scheduler is not None:
        raise UserError("--workers starts a cluster on this machine and --scheduler uses an "
                        "existing one: give one of them")
    if distributed and args.checkpoint:
        raise UserError("--checkpoint cannot be combined with --workers or --scheduler (the "
                        "tasks return their sums when they finish)")
    if args.scheduler is not None:
        from .distributed import ClusterError, check_scheduler_address
        try:
            check_scheduler_address(args.scheduler)
        except ClusterError as e:
            raise UserError(str(e)) from None
    interrupt.test_pause("load")
    try:
        scene = mi.load_file(str(scene_path), **defines)
    except Exception as e:  # Mitsuba reports parse and plugin errors as RuntimeError
        raise UserError(f"{scene_path}: {_clean(_root(e))}") from None
    _check_scene(scene, scene_path)
    try:
        progressive.check_film(scene)
        spp = args.spp
        if spp is None and args.time is None:
            spp = scene.sensors()[0].sampler().sample_count()
        if spp is not None:
            progressive.check_spp(spp)
    except ValueError as e:
        raise UserError(f"{scene_path}: {_clean(e)}") from None
    from .record import RunRecord
    record = RunRecord.for_scene(scene_path, scene.integrator(), mi.variant(), defines)
    runner = _run_distributed if distributed else _run
    acc = runner(scene, args, out, record, ints, scene_path)
    if acc is None:
        print(f"nothing rendered: stopped by {ints.received[0]} before a task finished a pass; "
              f"{out} not written", file=sys.stderr)
        return ints.status or 1
    ints.finish()
    with ints.deferred():
        interrupt.test_pause("write")
        _write(out, acc)
    rate = acc.spp * acc.s.shape[0] * acc.s.shape[1] / max(acc.seconds, 1e-9)
    stopped = ints.received[0] if ints.received else None
    note = f"; stopped by {stopped}" if stopped else ""
    where = ""
    if distributed:
        where = (f", {args.workers} Dask workers" if args.workers is not None
                 else f", Dask cluster {args.scheduler}")
    print(f"wrote {out} and {out.with_suffix('.png')} ({acc.s.shape[1]}x{acc.s.shape[0]}, "
          f"{acc.spp} spp in {acc.passes} passes, {acc.seconds:.2f} s, "
          f"{rate / 1e6:.2f} M samples/s, {mi.variant()}{where}{note})")
    if acc.stopped == "seeds":
        print(f"warning: stopped at the last seed {progressive.MAX_SEED} (seeds are 32-bit); "
              "start from a lower --seed for longer renders", file=sys.stderr)
    return ints.status


def _write(out, acc):
    """EXR (estimate, variance, ``acc``'s run record) and PNG preview, replaced together."""
    from . import progressive
    from .imageio import WriteError
    bad = int(np.count_nonzero(~np.isfinite(acc.s)))
    if bad:
        print(f"warning: {bad} non-finite pixel values (NaN/Inf) in the image", file=sys.stderr)
    try:
        progressive.write(out, acc, preview=True)
    except WriteError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"cannot write {out}: {e.strerror or _clean(e)}") from None


def _run(scene, args, out, record, ints, scene_path):
    """Progressive render with a progress bar, signal handling (interrupt.Interrupts: the
    first signal after a finished pass stops after the pass in flight, a second abandons it)
    and checkpoints.  Returns the accumulator."""
    from . import progressive
    stop = progressive.Stop()
    state = {"acc": None, "last_ckpt": time.monotonic()}
    bar = _progress_bar(args)

    class Keeper:
        def stop(self, name):
            stop.set(name)
            print(f"{name}: finishing the pass in flight, then writing {out} "
                  "(send again to abandon the pass)", file=sys.stderr, flush=True)

        def abandon(self, name):
            acc = state["acc"]
            try:
                _write(out, acc)
            except UserError as e:
                return f"{name} again: abandoned the pass in flight; error: {e}"
            return (f"{name} again: abandoned the pass in flight; wrote {out} with the "
                    f"{acc.spp} spp finished before it")

    def on_pass(acc):
        state["acc"] = acc
        ints.keeper = ints.keeper or Keeper()
        if bar is not None:
            w, h = acc.s.shape[1], acc.s.shape[0]
            rate = acc.spp * w * h / max(acc.seconds, 1e-9) / 1e6
            bar.set_postfix_str(f"{acc.spp} spp, {rate:.2f} M samples/s")
            bar.update((acc.spp if args.time is None else min(acc.seconds, args.time)) - bar.n)
        if args.checkpoint and time.monotonic() - state["last_ckpt"] >= args.checkpoint:
            with ints.deferred():
                _write(out, acc)
            state["last_ckpt"] = time.monotonic()

    try:
        try:
            return progressive.render(scene, spp=args.spp, time_budget=args.time,
                                      seed=args.seed, stop=stop, on_pass=on_pass, record=record)
        except UserError:
            raise
        except Exception as e:
            raise _render_failure(e, scene_path) from None
    finally:
        if bar is not None:
            bar.close()


def _run_distributed(scene, args, out, record, ints, scene_path):
    """The render on a Dask cluster (integrators.app.distributed) with one progress bar over
    it.  Signals as in-process: the first (once a task has finished a pass) stops every task
    after its pass in flight and writes the merge; a second abandons the tasks in flight and
    writes the tasks finished before it."""
    from . import distributed, progressive
    stop = progressive.Stop()
    stats: dict = {}
    bar = None

    class Keeper:
        def stop(self, name):
            stop.set(name)
            print(f"{name}: stopping the tasks after their pass in flight, then writing {out} "
                  "(send again to abandon them)", file=sys.stderr, flush=True)

        def abandon(self, name):
            with contextlib.suppress(Exception):
                cluster.client.cancel(stats.get("futures", []))
            try:
                acc = distributed.merge_results(list(stats.get("results", [])), record)
            except Exception as e:     # noqa: BLE001 - the process ends right after
                return f"{name} again: abandoned the tasks in flight; error: {_clean(e)}"
            if acc is None:
                return (f"{name} again: abandoned the tasks in flight; none had finished, "
                        f"{out} not written")
            try:
                _write(out, acc)
            except UserError as e:
                return f"{name} again: abandoned the tasks in flight; error: {e}"
            return (f"{name} again: abandoned the tasks in flight; wrote {out} with the "
                    f"{acc.spp} spp of the {len(stats['results'])} tasks finished before it")

    def on_progress(progress, elapsed):
        if progress.passes and ints.keeper is None:
            ints.keeper = Keeper()
        if bar is not None:
            w, h = scene_size
            rate = progress.spp * w * h / max(elapsed, 1e-9) / 1e6
            bar.set_postfix_str(f"{progress.spp} spp, {rate:.2f} M samples/s, "
                                f"{cluster.slots} workers")
            bar.update((progress.spp if args.time is None else min(elapsed, args.time))
                       - bar.n)

    scene_size = progressive.film_size(scene)
    spp = args.spp
    if spp is None and args.time is None:
        spp = scene.sensors()[0].sampler().sample_count()
    try:
        cluster = distributed.Cluster(workers=args.workers, scheduler=args.scheduler)
    except distributed.ClusterError as e:
        raise UserError(str(e)) from None
    try:
        bar = _progress_bar(args, total=spp)
        return distributed.render(cluster, scene_path, record, scene_size, spp=spp,
                                  time_budget=args.time, seed=args.seed, stop=stop,
                                  on_progress=on_progress, stats=stats)
    except UserError:
        raise
    except Exception as e:
        raise _render_failure(e, scene_path) from None
    finally:
        if bar is not None:
            bar.close()
        cluster.close()


def _progress_bar(args, total=None):
    if args.quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm
    if args.time is not None:
        return tqdm(total=args.time, unit="s", bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} s "
                    "[{elapsed}<{remaining}{postfix}]", file=sys.stderr)
    return tqdm(total=total or args.spp, unit="spp", file=sys.stderr)


def cmd_merge(args, ints) -> int:
    import integrators  # noqa: F401

    from . import progressive
    paths = [Path(p) for p in args.inputs]
    for p in paths:
        if not p.is_file():
            raise UserError(f"input not found: {p}" if not p.exists() else
                            f"input {p} is not a file")
    out = Path(args.output)
    _check_output(out)
    try:
        acc = progressive.merge([str(p) for p in paths])
    except (ValueError, RuntimeError, OSError) as e:
        raise UserError(_clean(e)) from None
    ints.finish()
    with ints.deferred():
        interrupt.test_pause("write")
        _write(out, acc)
    print(f"wrote {out} and {out.with_suffix('.png')}: {len(paths)} runs, {acc.spp} spp, "
          f"seeds {acc.seed_first}-{acc.seed_last}")
    return ints.status


def cmd_list(args, ints) -> int:
    from .. import registry
    from ..params import table
    for name, p in sorted(registry.plugins().items()):
        if args.markdown:
            print(f"**`{name}`** ({p.kind}): {p.summary}\n\n{table(p.params)}\n")
            continue
        print(f"{name} ({p.kind}): {p.summary}")
        for s in p.params:
            print(f"    {s.describe()}")
    return 0


def _one_line_warning(message, category, filename, lineno, line=None):
    return f"warning: {_clean(message)}\n"


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    ints = interrupt.install()
    saved_format = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    try:
        parser = _parser()
        args, extra = parser.parse_known_args(argv)
        if extra:
            sub = parser._subparsers._group_actions[0].choices[args.command]
            raise UserError(_usage_error(f"python -m integrators {args.command}",
                                         "unrecognized arguments: " + " ".join(extra),
                                         list(sub._option_string_actions)))
        return {"render": cmd_render, "list": cmd_list,
                "merge": cmd_merge}[args.command](args, ints)
    except SystemExit as e:              # --help
        return e.code if isinstance(e.code, int) else 0
    except UserError as e:
        if debug:
            raise
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:            # only where no handler could be installed
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # anything unexpected: still one line unless --debug
        if debug:
            raise
        root = _root(e)
        print(f"error: internal error: {type(root).__name__}: {_clean(root)} (run with --debug "
              "for details)", file=sys.stderr)
        return 1
    finally:
        warnings.formatwarning = saved_format
        with contextlib.suppress(Exception):
            sys.stdout.flush()
        interrupt.uninstall(ints)


if __name__ == "__main__":
    raise SystemExit(main())
