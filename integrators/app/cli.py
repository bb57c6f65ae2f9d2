"""Command line: ``python -m integrators render|list``.

    render SCENE.xml [-D name=value ...] [--spp N | --time S] [--seed S] [-o OUT.exr]
                     [--variant V] [--checkpoint SECONDS] [--quiet]
        Renders with the scene's own integrator, progressively in passes (see
        integrators.app.progressive), and writes OUT.exr (RGB + variance layer, the run record
        in the header: integrators.app.record) plus OUT.png (sRGB preview).  -D sets the XML ``$name`` defaults, as
        Mitsuba's own command line does.  Ctrl-C / SIGTERM finish the pass in flight, write what
        was accumulated and exit with 130 / 143.
    merge A.exr B.exr ... -o OUT.exr
        Sample-weighted mean of independent runs of the same scene and integrator; refuses
        runs whose records differ (scene content, integrator, parameters, variant, defines) or
        whose seed ranges overlap.
    list
        Every registered plugin with its parameters, defaults and allowed values (the same specs
        the plugins validate with).

Errors are one line on stderr with exit status 2 (``--debug`` shows the traceback).
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

import numpy as np


class UserError(Exception):
    """An error that is the user's to fix: printed as one line, no traceback."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m integrators",
                                description="Mitsuba 3 sampling-strategy integrators")
    p.add_argument("--debug", action="store_true", help="show Python tracebacks")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a Mitsuba XML scene")
    r.add_argument("scene", help="scene XML file")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="set an XML $NAME default (repeatable)")
    r.add_argument("--spp", type=_int_arg("--spp", 1), help="samples per pixel (default: scene's)")
    r.add_argument("--time", type=_seconds_arg("--time"), metavar="SECONDS",
                   help="time budget: stop after the pass that crosses it")
    r.add_argument("--checkpoint", type=_seconds_arg("--checkpoint"), metavar="SECONDS",
                   help="write the running estimate every SECONDS")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--seed", type=_int_arg("--seed", 0), default=0, help="sampler seed")
    r.add_argument("-o", "--output", help="output EXR (default: SCENE name in the current dir)")
    r.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb)")
    r.add_argument("--debug", action="store_true", help="show Python tracebacks")
    m = sub.add_parser("merge", help="merge independent renders of one scene")
    m.add_argument("inputs", nargs="+", help="EXR files written by render")
    m.add_argument("-o", "--output", required=True, help="merged EXR")
    m.add_argument("--debug", action="store_true", help="show Python tracebacks")
    ls = sub.add_parser("list", help="list plugins and their parameters")
    ls.add_argument("--markdown", action="store_true",
                    help="parameter tables in Markdown (as in the README)")
    ls.add_argument("--debug", action="store_true", help=argparse.SUPPRESS)
    return p


def _int_arg(flag, minimum):
    def conv(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{flag} = {s!r} is not an integer") from None
        if v < minimum:
            word = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
            raise argparse.ArgumentTypeError(f"{flag} = {v} must be {word}")
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


def _clean(msg: str) -> str:
    """Mitsuba error text without its source-file tags, on one line."""
    msg = re.sub(r"\[[\w./-]+\.cpp:\d+\]\s*", "", str(msg))
    if "Traceback (most recent call last):" in msg:
        # a Python plugin raised: keep Mitsuba's location and the exception's own message
        head, tail = msg.split("Traceback (most recent call last):", 1)
        last = [ln for ln in tail.strip().splitlines() if ln.strip()][-1].strip()
        msg = head + re.sub(r"^[\w.]*(Error|Exception):\s*", "", last)
    lines = [ln.strip() for ln in msg.strip().splitlines() if ln.strip()]
    return " ".join(lines)


def cmd_render(args) -> int:
    import integrators
    import mitsuba as mi

    scene_path = Path(args.scene)
    if not scene_path.is_file():
        raise UserError(f"scene file not found: {scene_path}")
    if args.variant:
        try:
            integrators.set_variant(args.variant)
        except (ValueError, RuntimeError) as e:
            raise UserError(str(e)) from None
    out = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    if out.suffix.lower() != ".exr":
        raise UserError(f"output {out}: the file name must end in .exr")
    out_dir = out.parent if str(out.parent) else Path(".")
    if out_dir.exists() and not os.access(out_dir, os.W_OK):
        raise UserError(f"output directory {out_dir} is not writable")
    defines = _defines(args.defines)
    try:
        scene = mi.load_file(str(scene_path), **defines)
    except Exception as e:  # Mitsuba reports parse and plugin errors as RuntimeError
        raise UserError(f"{scene_path}: {_clean(e)}") from None
    from .record import RunRecord
    record = RunRecord.for_scene(scene_path, scene.integrator(), mi.variant(), defines)
    acc, stopped = _run(scene, args, out, record)
    if acc is None:
        print("error: stopped before the first pass finished; nothing written", file=sys.stderr)
        return 130
    _write(out, acc)
    rate = acc.spp * acc.s.shape[0] * acc.s.shape[1] / max(acc.seconds, 1e-9)
    print(f"wrote {out} and {out.with_suffix('.png')} ({acc.s.shape[1]}x{acc.s.shape[0]}, "
          f"{acc.spp} spp in {acc.passes} passes, {acc.seconds:.2f} s, "
          f"{rate / 1e6:.2f} M samples/s, {mi.variant()})")
    if stopped:
        print(f"stopped by {stopped}: the output holds the {acc.spp} spp finished so far",
              file=sys.stderr)
        return 130 if stopped == "SIGINT" else 143
    return 0


def _write(out, acc):
    """EXR (estimate, variance, ``acc``'s run record) and PNG preview."""
    from . import progressive
    from .imageio import write_png
    bad = int(np.count_nonzero(~np.isfinite(acc.s)))
    if bad:
        print(f"warning: {bad} non-finite pixel values (NaN/Inf) in the image", file=sys.stderr)
    try:
        progressive.write(out, acc)
        write_png(out.with_suffix(".png"), acc.mean())
    except OSError as e:
        raise UserError(f"cannot write {out}: {e.strerror or e}") from None


def _run(scene, args, out, record):
    """Progressive render with a progress bar, signal handling and checkpoints.
    Returns (accumulator or None, name of the stopping signal or None)."""
    import signal

    from . import progressive
    stop = progressive.Stop()
    state = {"acc": None, "last_ckpt": time.monotonic(), "signal": None}

    def handler(signum, frame):
        name = signal.Signals(signum).name
        if state["signal"] is not None:      # second signal: abandon the pass in flight
            raise KeyboardInterrupt
        state["signal"] = name
        stop.set(name)
        print(f"\n{name}: finishing the pass in flight, then writing {out} "
              "(send again to abandon the pass)", file=sys.stderr)

    old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    bar = _progress_bar(args)

    def on_pass(acc):
        state["acc"] = acc
        if bar is not None:
            w, h = acc.s.shape[1], acc.s.shape[0]
            bar.set_postfix_str(f"{acc.spp} spp, {acc.spp * w * h / max(acc.seconds, 1e-9) / 1e6:.2f} M samples/s")
            bar.update((acc.spp if args.time is None else min(acc.seconds, args.time)) - bar.n)
        if args.checkpoint and time.monotonic() - state["last_ckpt"] >= args.checkpoint:
            _write(out, acc)
            state["last_ckpt"] = time.monotonic()

    try:
        try:
            acc = progressive.render(scene, spp=args.spp, time_budget=args.time, seed=args.seed,
                                     stop=stop, on_pass=on_pass, record=record)
        except KeyboardInterrupt:
            acc = state["acc"]
            state["signal"] = state["signal"] or "SIGINT"
        except Exception as e:
            raise UserError(f"rendering failed: {_clean(e)}") from None
    finally:
        if bar is not None:
            bar.close()
        for sig, h in old.items():
            signal.signal(sig, h)
    return acc, state["signal"]


def _progress_bar(args):
    if args.quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm
    if args.time is not None:
        return tqdm(total=args.time, unit="s", bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} s "
                    "[{elapsed}<{remaining}{postfix}]", file=sys.stderr)
    return tqdm(total=args.spp, unit="spp", file=sys.stderr)


def cmd_merge(args) -> int:
    import integrators  # noqa: F401

    from . import progressive
    paths = [Path(p) for p in args.inputs]
    for p in paths:
        if not p.is_file():
            raise UserError(f"input not found: {p}")
    out = Path(args.output)
    if out.suffix.lower() != ".exr":
        raise UserError(f"output {out}: the file name must end in .exr")
    try:
        acc = progressive.merge([str(p) for p in paths])
    except (ValueError, RuntimeError) as e:
        raise UserError(_clean(e)) from None
    _write(out, acc)
    print(f"wrote {out} and {out.with_suffix('.png')}: {len(paths)} runs, {acc.spp} spp, "
          f"seeds {acc.seed_first}-{acc.seed_last}")
    return 0


def cmd_list(args) -> int:
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


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    try:
        args = _parser().parse_args(argv)
        return {"render": cmd_render, "list": cmd_list, "merge": cmd_merge}[args.command](args)
    except UserError as e:
        if debug:
            raise
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # anything unexpected: still one line unless --debug
        if debug:
            raise
        print(f"error: {type(e).__name__}: {_clean(e)} (run with --debug for details)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
