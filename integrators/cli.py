"""Command line: ``python -m integrators render|list``.

    render SCENE.xml [-D name=value ...] [--spp N] [--seed S] [-o OUT.exr] [--variant V]
        Renders with the scene's own integrator and writes OUT.exr plus OUT.png (sRGB preview).
        -D sets the XML ``$name`` defaults, as Mitsuba's own command line does.
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
    r.add_argument("--seed", type=_int_arg("--seed", 0), default=0, help="sampler seed")
    r.add_argument("-o", "--output", help="output EXR (default: SCENE name in the current dir)")
    r.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb)")
    r.add_argument("--debug", action="store_true", help="show Python tracebacks")
    ls = sub.add_parser("list", help="list plugins and their parameters")
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
    t0 = time.perf_counter()
    try:
        image = mi.render(scene, spp=args.spp or 0, seed=args.seed)
        image = image.numpy() if hasattr(image, "numpy") else image
    except Exception as e:
        raise UserError(f"rendering {scene_path} failed: {_clean(e)}") from None
    seconds = time.perf_counter() - t0
    import numpy as np

    from .imageio import write_exr, write_png
    sensor = scene.sensors()[0]
    spp = args.spp or sensor.sampler().sample_count()
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        print(f"warning: {bad} non-finite pixel values (NaN/Inf) in the image", file=sys.stderr)
    meta = {"scene": str(scene_path), "integrator": str(scene.integrator()).replace("\n", " "),
            "spp": spp, "seed": args.seed, "variant": mi.variant(), "defines": defines}
    try:
        write_exr(out, image, meta)
        png = write_png(out.with_suffix(".png"), image)
    except OSError as e:
        raise UserError(f"cannot write {out}: {e.strerror or e}") from None
    print(f"wrote {out} and {png} ({image.shape[1]}x{image.shape[0]}, {spp} spp, "
          f"{seconds:.2f} s, {mi.variant()})")
    return 0


def cmd_list(args) -> int:
    from . import registry
    for name, p in sorted(registry.plugins().items()):
        print(f"{name} ({p.kind}): {p.summary}")
        for s in p.params:
            print(f"    {s.describe()}")
    return 0


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    try:
        args = _parser().parse_args(argv)
        return {"render": cmd_render, "list": cmd_list}[args.command](args)
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
