"""Grid search over the information network: one training per (d_cr, k) cell, heat maps of final metrics.

    python -m training.grid --config config/train_flock2d.yaml --data data/flock2d.npz --out runs/grid_flock2d \\
        --d-cr 2 3.5 5 --k 3 6 9 [--set training.epochs=6]

Parallel-safe and resumable: every cell trains in its own directory ``OUT/dcr<d>_k<k>/``,
claimed with an exclusive lock file; a finished cell (``cell.json``) is skipped, an
interrupted one resumes from its checkpoint (run the same command again, or several copies
of it at once to use several cores). ``--collect`` only gathers finished cells. Writes
``heatmap_<metric>_<mean|median>.png``, ``results.json`` and ``summary.md`` under ``--out``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from knode_swarm_ros.core import TrajectoryError, get_scenario, load_policy

from . import figures
from .common import ConfigError, final_metrics, write_json
from .evaluate import rollout_policy
from .train import DataError, DivergenceError, Trainer, _parse_set
from .common import load_config


def cell_name(d_cr: float, k: int) -> str:
    return f"dcr{d_cr:g}_k{k}"


def run_cell(cfg: Dict[str, Any], data_path: str, cell_dir: str, test_trajectories: int, log=print) -> Optional[Dict]:
    """Train and evaluate one cell unless finished or claimed by another process."""
    done = os.path.join(cell_dir, "cell.json")
    if os.path.exists(done):
        return json.load(open(done))
    os.makedirs(cell_dir, exist_ok=True)
    lock = os.path.join(cell_dir, ".lock")
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        log(f"{cell_dir}: claimed by another process (remove {lock} if that process died)")
        return None
    try:
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        resume = os.path.exists(os.path.join(cell_dir, "checkpoint.pt"))
        result: Dict[str, Any] = {"d_cr": cfg["policy"]["d_cr"], "k": cfg["policy"]["k"]}
        try:
            Trainer(cfg, data_path, cell_dir, resume=resume, progress=False, log=lambda *a: None).run()
        except DivergenceError as exc:
            result["error"] = str(exc)
        if "error" not in result:
            from knode_swarm_ros.core import load_trajectories
            policy = load_policy(os.path.join(cell_dir, "policy.pt"))
            data = load_trajectories(data_path)
            truth = data.states[data.split("test")[:test_trajectories]]
            pred = rollout_policy(policy, truth[:, 0], truth.shape[1] - 1)
            result.update(final_metrics(get_scenario(policy.scenario), pred, truth, dt=policy.dt))
        write_json(done, result)
        log(f"{cell_dir}: done")
        return result
    finally:
        if os.path.exists(lock):
            os.unlink(lock)


def collect(out: str, scenario: str, d_crs: List[float], ks: List[int]) -> Dict[str, Any]:
    names = ["avd_final", "amd_final"] if scenario == "flock2d" else ["amd_final", "pod_kld"]
    cells = {}
    for d in d_crs:
        for k in ks:
            path = os.path.join(out, cell_name(d, k), "cell.json")
            if os.path.exists(path):
                cells[(d, k)] = json.load(open(path))
    tables: Dict[str, Any] = {}
    for name in names:
        for stat, fn in (("mean", np.mean), ("median", np.median)):
            grid = np.full((len(d_crs), len(ks)), np.nan)
            for i, d in enumerate(d_crs):
                for j, k in enumerate(ks):
                    c = cells.get((d, k))
                    if c is not None and name in c:
                        grid[i, j] = fn(c[name])
            tables[f"{name}_{stat}"] = grid.tolist()
            figures.heatmap(os.path.join(out, f"heatmap_{name}_{stat}.png"), grid, d_crs, ks,
                            f"{stat} {name.replace('_final', ' (final)')}")
    truth = next((c for c in cells.values() if "truth_amd_final" in c), None)
    results = {"scenario": scenario, "d_cr": d_crs, "k": ks, "tables": tables,
               "finished": [cell_name(d, k) for (d, k) in cells],
               "errors": {cell_name(d, k): c["error"] for (d, k), c in cells.items() if "error" in c},
               "truth": None if truth is None else {key: float(np.mean(truth[key])) for key in truth if key.startswith("truth_")}}
    write_json(os.path.join(out, "results.json"), results)
    lines = [f"# Grid search: {scenario}", "", f"{len(cells)} of {len(d_crs) * len(ks)} cells finished.", ""]
    for key, grid in tables.items():
        lines += [f"## {key}", "", "| d_cr \\ k | " + " | ".join(map(str, ks)) + " |",
                  "| --- " * (len(ks) + 1) + "|"]
        for d, row in zip(d_crs, grid):
            lines.append(f"| {d:g} | " + " | ".join("-" if not np.isfinite(v) else f"{v:.3g}" for v in row) + " |")
        lines.append("")
    if results["truth"]:
        lines.append("Ground truth: " + ", ".join(f"{k} {v:.3g}" for k, v in results["truth"].items()))
    open(os.path.join(out, "summary.md"), "w").write("\n".join(lines) + "\n")
    return results


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m training.grid", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--d-cr", type=float, nargs="+", default=[2.0, 3.5, 5.0])
    parser.add_argument("--k", type=int, nargs="+", default=[3, 6, 9])
    parser.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE", help="override a config field")
    parser.add_argument("--trajectories", type=int, default=20, help="test trajectories per cell evaluation")
    parser.add_argument("--collect", action="store_true", help="only gather finished cells")
    args = parser.parse_args(argv)
    try:
        base = _parse_set(args.set)
        cfg0 = load_config(args.config, base)
        torch.set_num_threads(cfg0["training"]["threads"])
        if not args.collect:
            for d in args.d_cr:
                for k in args.k:
                    cfg = load_config(args.config, {**base, "policy.d_cr": d, "policy.k": k})
                    run_cell(cfg, args.data, os.path.join(args.out, cell_name(d, k)), args.trajectories)
        results = collect(args.out, cfg0["scenario"], args.d_cr, args.k)
    except (ConfigError, DataError, TrajectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{len(results['finished'])} cells finished; wrote {args.out}/results.json and heat maps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
