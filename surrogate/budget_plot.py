"""The budget comparison's figure (compare.png): four panels a person reads at a glance.

1. test error (mean: solid, p95: dashed) against wall time, per arm;
2. error across the parameter domain (first random parameter; binned mean per arm): where each arm errs;
3. the reservoir's reuse histogram (uses per trajectory, in units of a FIFO pass);
4. where loss-driven sampling put its simulations, against the training loss it saw there.
"""

from __future__ import annotations

import numpy as np

COLORS = {"precomputed": "tab:red", "fifo": "tab:gray", "reservoir": "tab:blue", "reservoir_loss": "tab:green"}


def plot_budget(path, result: dict, domains: dict) -> None:
    """Draw compare.png from ``budget_compare``'s result dict; ``domains``: datasets.param_domains(pde)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    (ax_time, ax_dom), (ax_reuse, ax_prop) = axes
    arms = result["arms"]
    for r in arms:
        c = COLORS.get(r["arm"], "black")
        t = [p["elapsed"] for p in r["curve"]]
        ax_time.plot(t, [p["test_mean"] for p in r["curve"]], "-o", color=c, ms=3, label=f"{r['arm']} mean")
        ax_time.plot(t, [p["test_p95"] for p in r["curve"]], "--", color=c, alpha=0.7, label=f"{r['arm']} p95")
    ax_time.set(yscale="log", xlabel="wall time of the arm (s)", ylabel="test relative L2",
                title="test error against wall time")
    ax_time.legend(fontsize=7, ncol=2)

    random = [n for n in result["param_names"] if domains[n][0] != "fixed"]
    if random:
        name = random[0]
        j = result["param_names"].index(name)
        x = np.asarray(result["test_params"]["test"])[:, j]
        log = domains[name][0] == "loguniform"
        edges = np.geomspace(x.min(), x.max() * 1.0001, 11) if log else np.linspace(x.min(), x.max() * 1.0001, 11)
        which = np.clip(np.digitize(x, edges) - 1, 0, 9)
        mid = np.sqrt(edges[:-1] * edges[1:]) if log else (edges[:-1] + edges[1:]) / 2
        for r in arms:
            e = np.asarray(r["errors"]["test"])
            ax_dom.plot(mid, [e[which == b].mean() if (which == b).any() else np.nan for b in range(10)], "-o",
                        ms=3, color=COLORS.get(r["arm"], "black"), label=r["arm"])
        ax_dom.set(xscale="log" if log else "linear", yscale="log", xlabel=f"{name} (test set, binned)",
                   ylabel="mean test relative L2", title="where each arm errs")
        ax_dom.legend(fontsize=8)
    else:
        ax_dom.text(0.5, 0.5, "no random parameter", ha="center", transform=ax_dom.transAxes)

    with_reuse = [r for r in arms if r["reuse"]]
    if with_reuse:
        top = max(max(r["reuse"]) for r in with_reuse)
        bins = np.linspace(0, max(top, 1.0) * 1.05, 30)
        for r in with_reuse:
            ax_reuse.hist(r["reuse"], bins=bins, alpha=0.5, color=COLORS.get(r["arm"], "black"), label=r["arm"])
        ax_reuse.legend(fontsize=8)
    ax_reuse.set(xlabel="uses per trajectory (1 = one FIFO pass)", ylabel="trajectories",
                 title="reservoir reuse")

    steered = next((r for r in arms if r["arm"] == "reservoir_loss" and r["density"]), None)
    if steered and random:
        d = steered["density"]
        edges = np.asarray(d["edges"])
        kind, low, high, _ = domains[random[0]]
        if kind == "loguniform":
            x_edges = np.exp(np.log(low) + edges * (np.log(high) - np.log(low)))
        else:
            x_edges = low + edges * (high - low)
        ax_prop.bar(x_edges[:-1], d["counts"], width=np.diff(x_edges), align="edge", alpha=0.5,
                    color=COLORS["reservoir_loss"], label="simulations proposed")
        ax_prop.set(xscale="log" if kind == "loguniform" else "linear", xlabel=random[0], ylabel="simulations")
        twin = ax_prop.twinx()
        twin.plot(np.sqrt(x_edges[:-1] * x_edges[1:]) if kind == "loguniform" else (x_edges[:-1] + x_edges[1:]) / 2,
                  d["loss"], "k-o", ms=3, label="recent training loss")
        twin.set(ylabel="mean recent per-sample loss (rel. L2, normalized units)")
        ax_prop.legend(loc="upper left", fontsize=8)
        twin.legend(loc="upper right", fontsize=8)
        ax_prop.set_title("loss-driven sampling: where it simulated")
    else:
        ax_prop.text(0.5, 0.5, "no loss-driven arm", ha="center", transform=ax_prop.transAxes)
        ax_prop.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
