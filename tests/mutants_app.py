"""Mutants of the command line's plumbing shared by the plugins (see tests/mutation.py)."""

MUTANTS = [
    # a render() override calling Mitsuba's render binding without re-installing Python's
    # SIGINT handler: Ctrl-C is swallowed by the nested Mitsuba handlers
    ("base-render-without-python-sigint", "integrators/plugins/base.py",
     "        with _python_sigint():\n            return self._base.render(",
     "        if True:\n            return self._base.render(", ["test_corpus.py"]),
]
