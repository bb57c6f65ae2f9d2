"""Mutants for issue 19 (distributed renders, the spectral colour checker): planted bugs that
tests/test_distributed.py and tests/test_colour_checker.py must catch.  Same form as
tests/mutation.py's list; ``python tests/mutation.py --only NAME`` runs one."""

MUTANTS = [
    # a task's seeds start one early: consecutive tasks share a seed (correlated samples)
    ("distributed-seed-range-off-by-one", "integrators/app/distributed.py",
     "        out.append((seed + at, tuple(passes[at:at + k])))",
     "        out.append((seed + at - (t > 0), tuple(passes[at:at + k])))",
     ["test_distributed.py"]),
    # the last pass keeps the full pass size: the render has more samples than asked
    ("distributed-last-pass-not-trimmed", "integrators/app/distributed.py",
     "    return [n] * (count - 1) + [spp - n * (count - 1)]",
     "    return [n] * count",
     ["test_distributed.py"]),
    # a task draws its seeds from a per-process counter instead of its range: a retried task
    # (another process) renders other seeds, and the image depends on the scheduling
    ("distributed-seeds-from-the-process", "integrators/app/distributed.py",
     "        seed = spec.seed_first + k\n",
     "        seed = spec.seed_first + k + (os.getpid() % 7)\n",
     ["test_distributed.py"]),
    # every worker runs Dr.Jit on every core: workers x threads > cores
    ("distributed-threads-not-divided", "integrators/app/distributed.py",
     "    _THREADS = max(1, _cores() // int(slots))",
     "    _THREADS = _cores()",
     ["test_distributed.py"]),
    # the tasks never see the stop event: Ctrl-C waits for the whole render
    ("distributed-stop-ignored", "integrators/app/distributed.py",
     "    return bool(Event(spec.stop_event).is_set())",
     "    return False",
     ["test_distributed.py"]),
    # an estimator bug the spectral colour checker sees: MIS weights 5 % too large (every
    # integrator).  (Most planted estimator bugs cannot show in this scene by design: one
    # environment light, paths of one bounce, no roulette or splitting; they are the other
    # tests' targets.)
    ("colour-checker-mis-weights-1.05", "integrators/sampling/mis.py",
     "return [x * inv_total for x in s]",
     "return [x * inv_total * 1.05 for x in s]",
     ["test_colour_checker.py"]),
]
