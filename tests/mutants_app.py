"""Mutants of the command line's plumbing shared by the plugins (see tests/mutation.py)."""

MUTANTS = [
    # a render() override calling Mitsuba's render binding without re-installing Python's
    # SIGINT handler: Ctrl-C is swallowed by the nested Mitsuba handlers
    ("base-render-without-python-sigint", "integrators/plugins/base.py",
     "        with _python_sigint():\n            return self._base.render(",
     "        if True:\n            return self._base.render(", ["test_corpus.py"]),
    # no throw-away render-binding call before the first render: Mitsuba's saved "previous"
    # SIGINT handler is still SIG_DFL during the first install, and a SIGINT then kills the
    # command with no line
    ("no-mitsuba-sigint-priming", "integrators/app/interrupt.py",
     "    if variant is None or variant in _primed:\n        return\n",
     "    if True:\n        return\n", ["test_corpus.py"]),
]
