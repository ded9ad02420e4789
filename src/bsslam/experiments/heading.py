"""The paper's information-gain experiment (Fig. 11, spec §10).

A stationary robot faces the curved wall and keeps observing it. Its initial heading is
uncertain (σ₀ = 0.01, 0.05, 0.2 rad); the estimated σ_φ over updates, averaged over runs,
shows how much heading information the EKF believes it gains — in a consistent filter it
cannot fall far below what the first observation allows, as the map was built from the
robot itself.
"""

from __future__ import annotations

import csv
from functools import partial
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.io.atomic_file import atomic_write
from bsslam.parallel import run_all
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import SplineSLAM

DEFAULT_SIGMAS_RAD = (0.01, 0.05, 0.2)


def _one_run(run: tuple[float, int], updates: int, config: SLAMConfig, sim: SimConfig) -> np.ndarray:
    sigma0, seed = run
    data = simulate(get_world("curved-wall"), sim, seed=seed, steps=updates + 1)
    rng = np.random.default_rng([seed, 7])
    truth = data.ground_truth.poses[0]
    # the filter starts from a heading drawn from its own prior around the truth
    start = truth + np.array([0.0, 0.0, rng.normal(0.0, sigma0)])
    slam = SplineSLAM(config, initial_pose=start, initial_covariance=np.diag([0.0, 0.0, sigma0 ** 2]))
    sig = []
    for k, frame in enumerate(data):
        slam.step(None, frame.scan)  # stationary: no motion, no prediction
        if k:  # the first scan only builds the map; updates start with the second
            sig.append(np.sqrt(slam.pose_covariance[2, 2]))
    return np.array(sig)


def heading_gain_experiment(sigmas_rad=DEFAULT_SIGMAS_RAD, runs: int = 50, updates: int = 30, seed: int = 0,
                            workers: int | None = None, progress=None,
                            scheduler: str | None = None, base: SLAMConfig | None = None) -> dict[float, np.ndarray]:
    """Mean estimated σ_φ (rad) after each update (index 0 = after the first update, i.e.
    the second scan; the first builds the map) per σ₀. The ``runs × len(sigmas_rad)`` runs
    go where ``workers``/``scheduler`` say (see :func:`bsslam.parallel.run_all`). ``base``: the
    filter's configuration before it is matched to the simulator (the library's defaults
    when None; ``bsslam experiment heading-gain`` passes the paper's update,
    :func:`bsslam.experiments.consistency.paper_filter`, with the chosen estimator)."""
    sim = SimConfig()
    config = simulation_config(base or SLAMConfig(), sim)
    sigmas = [float(s0) for s0 in sigmas_rad]
    # one batch for every σ₀: a cluster is started once and kept busy across them
    batch = [(s0, s) for s0 in sigmas for s in range(seed, seed + runs)]
    fn = partial(_one_run, updates=updates, config=config, sim=sim)
    res = run_all(fn, batch, workers=workers, scheduler=scheduler, progress=progress)
    return {s0: np.mean(res[i * runs:(i + 1) * runs], axis=0) for i, s0 in enumerate(sigmas)}


def write_heading_gain(result: dict[float, np.ndarray], run_dir: Path) -> list[Path]:
    """``heading_sigma.csv`` (update,sigma0_rad,mean_sigma_phi_rad) and ``heading_sigma.png``."""
    from bsslam.viz import new_figure, plot_sigma_over_updates, save_figure

    run_dir = Path(run_dir)
    csv_path, png_path = run_dir / "heading_sigma.csv", run_dir / "heading_sigma.png"
    with atomic_write(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["update", "sigma0_rad", "mean_sigma_phi_rad"])
        for s0, sig in result.items():
            for k, v in enumerate(sig):
                w.writerow([k + 1, f"{s0:g}", f"{v:.6g}"])
    fig = new_figure()
    ax = fig.add_subplot()
    first = next(iter(result.values()))
    plot_sigma_over_updates(ax, np.arange(1, first.size + 1), result)
    save_figure(fig, [png_path])
    return [csv_path, png_path]
