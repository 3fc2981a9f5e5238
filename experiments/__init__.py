"""Experiments over the library: which data route or training mode gives the better surrogate for a cost.

    compare                 train the same model on a cache and on the stream; the CLI's ``compare``
    budget                  the same at equal wall clock or equal simulation budget, arm by arm, resumable
    interactive_compare     one-step, pushforward, oracle, noise and solver-in-the-loop training side by side
    interactive_report      what that comparison writes: its tables, curves, figures and verdicts
    rollout_figure          the error-against-time and snapshot figure of those comparisons
    command                 the CLI's ``compare``: run_compare(CompareCommand(...)) picks one of the three

Above ``surrogate`` and ``datasets`` (it imports both); nothing in the library imports it.
"""
