"""Compare the Theil-Sen and the Kalman wear trends (docs/wear-trend.md).

1. The bundled series (``online_backlash.history.series``): 60 daily 60 s snapshots with the
   machine's hour meter, tracked through the recursive estimator into a temporary store, as
   ``online-backlash demo`` does; the trends run on machine hours, one point per snapshot.
2. A synthetic year of daily estimates whose wear rate triples on day 240 (1e-4 -> 3e-4 deg per
   operating hour, 2 operating hours a day), read through an estimator that lags the play by
   10 operating hours and whose estimates scatter with correlated noise (AR(1), 0.8) of 0.003 deg
   while reporting a standard deviation of 0.002 deg.

For each: the wear rate now with its interval, the forecast of the limit crossing with its
interval against the truth, and the share of the estimates inside each band. Run from the
repository root (a few seconds):

    python scripts/compare_wear_trends.py [--plots docs/img]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from online_backlash.history import HistoryStore, bundled_wear_series, plot_wear, wear_report
from online_backlash.history.report import WearReport
from online_backlash.history.trend import summarise
from online_backlash.tracking import track_series


def band_shares(trend, x: np.ndarray, z: np.ndarray) -> tuple[float, float]:
    """Share of the estimates inside the confidence band and inside the prediction band."""
    lo_c, hi_c = trend.band(x)
    lo_p, hi_p = trend.prediction_band(x)
    return float(np.mean((z >= lo_c) & (z <= hi_c))), float(np.mean((z >= lo_p) & (z <= hi_p)))


def row(name: str, summary, x: np.ndarray, z: np.ndarray, true_rate: float, true_hours: float) -> str:
    t, f = summary.trend, summary.forecast
    conf, pred = band_shares(t, x, z)
    inside = "yes" if f.to_limit_low <= true_hours <= f.to_limit_high else "no"
    return (
        f"| {name} | {t.slope:.4g} [{t.slope_low:.4g}, {t.slope_high:.4g}] (true {true_rate:.4g}) "
        f"| {f.to_limit:.4g} [{f.to_limit_low:.4g}, {f.to_limit_high:.4g}] (true {true_hours:.4g}, inside: {inside}) "
        f"| {conf:.0%} | {pred:.0%} |"
    )


HEADER = (
    "| trend | wear rate now, deg/h [95 %] | hours to the limit [95 %] | estimates in the confidence band "
    "| in the prediction band |\n|---|---|---|---|---|"
)


def bundled(plots: Path | None) -> None:
    series = bundled_wear_series()
    truth = series.manifest
    print("## bundled series\n")
    print(HEADER)
    with tempfile.TemporaryDirectory() as folder, HistoryStore(Path(folder) / "wear.db", create=True) as store:
        track_series(series, store)
        for method in ("theil-sen", "kalman"):
            report: WearReport = wear_report(store, series.gearbox, method=method)
            s = report.summary
            x, z = report.column("machine_hours"), report.column("backlash_deg")
            true_hours = truth["true_hours_at_limit"] - s.last_x
            print(row(method, s, x, z, truth["true_rate_deg_per_hour"], true_hours))
            if plots is not None:
                plot_wear(report, plots / f"wear-trend-bundled-{method}.png")


def synthetic_year(seed: int = 2026) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    days = np.arange(365)
    hours = 2.0 * (days + 1)
    bend = hours[240]

    def play(h: np.ndarray) -> np.ndarray:
        return 0.20 + 1e-4 * h + np.where(h > bend, 2e-4 * (h - bend), 0.0)

    noise = np.empty(days.size)
    noise[0] = rng.normal(0.0, 0.003)
    for k in range(1, days.size):  # AR(1), stationary std 0.003
        noise[k] = 0.8 * noise[k - 1] + rng.normal(0.0, 0.003 * np.sqrt(1 - 0.8**2))
    lag_h = 10.0
    return {
        "time_unix_s": 1.7e9 + days * 86400.0,
        "operating_hours": hours,
        "load_revolutions": 100.0 * hours,
        "backlash_deg": play(hours - lag_h) + noise,
        "backlash_std_deg": np.full(days.size, 0.002),
        "lag_h": lag_h,
        "play": play,
    }


def year(plots: Path | None) -> None:
    data = synthetic_year()
    play, lag_h = data.pop("play"), data.pop("lag_h")
    limit = 0.40
    last = data["operating_hours"][-1]
    true_hours = last + (limit - play(np.array([last]))[0]) / 3e-4 - last
    print("\n## synthetic year, wear rate x3 on day 240\n")
    print(HEADER)
    for method in ("theil-sen", "kalman"):
        s = summarise(**data, limit_deg=limit, method=method, lag_hours=lag_h)
        print(row(method, s, data["operating_hours"], data["backlash_deg"], 3e-4, true_hours))
        if plots is not None:
            _plot_year(s, data, play, limit, plots / f"wear-trend-year-{method}.png")


def _plot_year(summary, data: dict, play, limit: float, path: Path) -> None:
    from matplotlib.figure import Figure

    t = summary.trend
    x = data["operating_hours"]
    grid = np.linspace(0.0, x[-1] + 250.0, 400)
    fig = Figure(figsize=(8.0, 4.8), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(x, data["backlash_deg"], ".", ms=3, color="tab:blue", label="estimates (lagged 10 h, correlated noise)")
    ax.plot(grid, play(grid), color="k", lw=1, label="true play")
    ax.fill_between(grid, *t.prediction_band(grid), color="tab:orange", alpha=0.12, lw=0, label="prediction band (95%)")
    ax.fill_between(grid, *t.band(grid), color="tab:orange", alpha=0.35, lw=0, label="confidence band (95%)")
    ax.plot(grid, t.line(grid), color="tab:orange", label=f"trend ({t.method})")
    ax.axhline(limit, color="tab:red", ls="--", lw=1, label="limit")
    ax.set_xlabel("operating hours since new")
    ax.set_ylabel("backlash, deg")
    ax.set_title(f"synthetic year, wear rate x3 on day 240: {t.method}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.savefig(path, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plots", type=Path, help="folder for the figures")
    args = parser.parse_args()
    bundled(args.plots)
    year(args.plots)


if __name__ == "__main__":
    main()
