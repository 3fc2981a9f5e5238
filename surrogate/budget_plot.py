"""The budget comparison's figure (compare.png): four panels a person reads at a glance.

1. test error (mean: solid, p95: dashed) against wall time, per arm;
2. error across the parameter domain (first random parameter; binned mean per arm): where each arm errs;
3. the reservoir's reuse histogram (uses per trajectory, in units of a FIFO pass);
4. where loss-driven sampling put its simulations, against the training loss it saw there.
"""

from __future__ import annotations

import numpy as np

COLORS = {"precomputed": "tab:red", "fifo": "tab:gray", "reservoir": "tab:blue", "reservoir_loss": "tab:green",
          "reservoir_active": "tab:purple", "reservoir_generative": "tab:olive"}


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

    draw_reuse(ax_reuse, {r["arm"]: r["reuse"] for r in arms if r["reuse"]})
    # the active arm when there is one, else the loss-driven one
    steered = next((r for name in ("reservoir_active", "reservoir_generative", "reservoir_loss") for r in arms
                    if r["arm"] == name and r["density"]), None)
    if steered and random:
        draw_proposal(ax_prop, steered["density"], random[0], domains[random[0]], COLORS[steered["arm"]])
    else:
        ax_prop.text(0.5, 0.5, "no loss-driven arm", ha="center", transform=ax_prop.transAxes)
        ax_prop.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def draw_reuse(ax, reuse: dict) -> None:
    """Histogram of uses per trajectory ({label: [reuse values]}; 1 = one FIFO pass)."""
    if reuse:
        top = max(max(v) for v in reuse.values())
        bins = np.linspace(0, max(top, 1.0) * 1.05, 30)
        for label, values in reuse.items():
            ax.hist(values, bins=bins, alpha=0.5, color=COLORS.get(label, "tab:blue"), label=label)
        ax.legend(fontsize=8)
    ax.set(xlabel="uses per trajectory (1 = one FIFO pass)", ylabel="trajectories", title="reservoir reuse")


def draw_proposal(ax, density: dict, name: str, domain: tuple, color: str = COLORS["reservoir_loss"]) -> None:
    """Where the proposal put its simulations (bars) against the recent training loss there (line), along
    parameter ``name`` with domain (kind, low, high, options); ``density`` from ParamProposal.density()."""
    edges = np.asarray(density["edges"])
    kind, low, high, _ = domain
    log = kind == "loguniform"
    x = np.exp(np.log(low) + edges * (np.log(high) - np.log(low))) if log else low + edges * (high - low)
    ax.bar(x[:-1], density["counts"], width=np.diff(x), align="edge", alpha=0.5, color=color,
           label="simulations proposed")
    ax.set(xscale="log" if log else "linear", xlabel=name, ylabel="simulations",
           title="loss-driven sampling: where it simulated")
    twin = ax.twinx()
    twin.plot(np.sqrt(x[:-1] * x[1:]) if log else (x[:-1] + x[1:]) / 2, density["loss"], "k-o", ms=3,
              label="recent training loss")
    twin.set(ylabel="mean recent per-sample loss (rel. L2, normalized units)")
    ax.legend(loc="upper left", fontsize=8)
    twin.legend(loc="upper right", fontsize=8)


def plot_reservoir_run(path, report: dict) -> None:
    """reservoir.png of a training run through a reservoir: reuse histogram and, along the first random
    parameter, where the simulations went against the loss (``ReservoirStream.report()``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_reuse, ax_prop) = plt.subplots(1, 2, figsize=(12, 4.2))
    draw_reuse(ax_reuse, {"reservoir": report["reuse"]})
    if report.get("param"):
        draw_proposal(ax_prop, report["density"], report["param"], report["domain"])
        ax_prop.set_title(f"simulations ({report['proposal']} proposal) and training loss")
    else:
        ax_prop.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
