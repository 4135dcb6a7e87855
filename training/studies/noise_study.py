"""The noise study (docs/noise.md): what learning from motion capture costs, per noise level and rate.

    nice -n 10 python -m training.studies.noise_study --out out/noise_study \
        --noise 0 2 10 --rates 120 --objectives one_step multi_step --max-minutes 8

Per case (noise in mm x rate in Hz) it records ``--episodes`` episodes of ``--seconds`` s of the
flock2d ground truth as PoseStamped bags (:func:`write_mocap_bag`: noise, 0.5 ms stamp jitter,
1 % drops, one robot occluded for 0.4 s in every fourth episode), imports them all in one
``training.import_bag`` call with the defaults (resampled at the truth's 100 Hz), trains with each
``--objectives`` config (``one_step``: config/train_flock2d.yaml, derivatives from the importer's
smoother; ``multi_step``: config/train_flock2d_multistep.yaml, trajectory matching on positions,
fine-tuning that case's one-step run), both holding out a fifth of the episodes for validation
(``data.val_fraction``, as config/train_recorded.yaml), and evaluates the policy with ``training.evaluate`` on
``--test-starts`` clean held-out starts of the same truth. Every step runs as its own command with
its log in the case's directory; a step whose output exists is skipped, so a killed study resumes
where it stopped. One row per (case, objective) goes to ``OUT/results.jsonl`` (final avd and amd
over the held-out starts with their spread, the importer's noise estimate, minutes, the load
average beside it) and ``OUT/summary.md`` is rewritten from all rows; progress goes to
``OUT/study.log``.

A mocap driver publishes geometry_msgs/PoseStamped per robot at a fixed rate; what reaches the bag
differs from the truth by Gaussian position noise, jittered header stamps, dropped messages and
occlusions (a robot unseen for a while). :func:`write_mocap_bag` makes such a bag from one
ground-truth trajectory (``states[T, n, d]`` every ``dt``, as ``python -m training.generate``
writes them), positions taken at the jittered stamps by cubic interpolation of the truth.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from knode_swarm_ros.bag import POSE_STAMPED, BagWriter, ns_to_stamp
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError, RunError

__all__ = ['MocapNoise', 'write_mocap_bag', 'truth_at', 'main']

ROOT = Path(__file__).resolve().parents[2]
#: objective -> training config (repository-relative)
CONFIGS = {'one_step': 'config/train_flock2d.yaml', 'multi_step': 'config/train_flock2d_multistep.yaml'}
TOPICS = '/mocap/robot_*/pose'


@dataclass
class MocapNoise:
    """What the recording adds to the truth."""

    rate: float = 120.0  # Hz, the driver's publishing rate
    noise: float = 0.002  # m, standard deviation of the position noise per axis
    jitter: float = 0.5e-3  # s, standard deviation of the header stamps about the nominal times
    drop: float = 0.01  # fraction of messages lost
    occlusion: Optional[Tuple[int, float, float]] = None  # (robot, start s, duration s) unseen
    latency: float = 2e-3  # s, mean receive delay (the log time); exponential, so some arrive late


def truth_at(states: np.ndarray, dt: float, times: np.ndarray, p: int) -> Tuple[np.ndarray, np.ndarray]:
    """Positions and velocities ``[len(times), n, p]`` of a ground-truth trajectory ``states[T, n, d]``
    (positions then velocities) at ``times`` (s): cubic Hermite between frames from both."""
    T = states.shape[0]
    k = np.clip(np.floor(times / dt).astype(int), 0, T - 2)
    s = (times / dt - k)[:, None, None]
    p0, p1 = states[k, :, :p], states[k + 1, :, :p]
    v0, v1 = states[k, :, p : 2 * p] * dt, states[k + 1, :, p : 2 * p] * dt
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    pos = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    vel = (d00 * p0 + d10 * v0 + d01 * p1 + d11 * v1) / dt
    return pos, vel


def write_mocap_bag(
    path, states: np.ndarray, dt: float, mocap: MocapNoise, rng: np.random.Generator, p: int = 2
) -> dict:
    """Write ``states[T, n, d]`` (positions ``[..., :p]``, velocities ``[..., p:2p]``) as a PoseStamped
    bag on ``/mocap/robot_<i>/pose``, as :class:`MocapNoise` says; the truth of what was written:
    ``{'messages', 'dropped', 'late'}``. Messages enter the bag in receive (log) order."""
    T, n = states.shape[:2]
    nominal = np.arange(0.0, (T - 1) * dt - 2 * mocap.jitter, 1.0 / mocap.rate) + mocap.jitter * 4
    rows = []
    dropped = 0
    for i in range(n):
        t = nominal + rng.normal(0.0, mocap.jitter, nominal.size)
        keep = rng.random(t.size) >= mocap.drop
        dropped += int((~keep).sum())
        if mocap.occlusion is not None and mocap.occlusion[0] == i:
            _, a, d = mocap.occlusion
            keep &= (t < a) | (t > a + d)
        t = t[keep]
        pos, _ = truth_at(states[:, i : i + 1], dt, t, p)
        pos = pos[:, 0] + rng.normal(0.0, mocap.noise, (t.size, p))
        log = t + rng.exponential(mocap.latency, t.size)
        rows.extend((float(lg), float(ts), i, x) for lg, ts, x in zip(log, t, pos))
    rows.sort(key=lambda r: r[0])
    late = 0
    last = {}
    with BagWriter(Path(path)) as bag:
        for log, stamp, i, x in rows:
            late += int(stamp < last.get(i, -1.0))
            last[i] = max(stamp, last.get(i, -1.0))
            stamp_ns = int(round(stamp * 1e9))
            xyz = list(map(float, x)) + [0.0] * (3 - p)
            bag.write(
                f'/mocap/robot_{i}/pose',
                POSE_STAMPED,
                {
                    'header': {'stamp': ns_to_stamp(stamp_ns), 'frame_id': 'world'},
                    'pose': {
                        'position': dict(zip('xyz', xyz)),
                        'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
                    },
                },
                stamp_ns,
                log_time_ns=int(round(log * 1e9)),
            )
    return {'messages': len(rows), 'dropped': dropped, 'late': late}


def case_name(noise_mm: float, rate: float) -> str:
    """Directory of one case: ``n2mm_120hz``."""
    return f'n{noise_mm:g}mm_{rate:g}hz'


class Study:
    """One study directory: the truth, the cases, the log and the rows (resumable)."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.out = Path(args.out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.rows_path = self.out / 'results.jsonl'

    def log(self, msg: str) -> None:
        line = f'{time.strftime("%Y-%m-%d %H:%M:%S")} load {os.getloadavg()[0]:.1f} {msg}'
        print(line, flush=True)
        with open(self.out / 'study.log', 'a') as f:
            f.write(line + '\n')

    def rows(self) -> List[Dict[str, Any]]:
        if not self.rows_path.is_file():
            return []
        return [json.loads(line) for line in self.rows_path.read_text().splitlines() if line.strip()]

    def run(self, cmd: List[str], log: Path, done: Path) -> None:
        """Run one step (``python -m ...``) unless ``done`` exists; its output goes to ``log``."""
        if done.exists():
            return
        self.log(f'run {" ".join(cmd)} (log {log})')
        with open(log, 'w') as f:
            rc = subprocess.call([sys.executable, '-m'] + cmd, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT)
        if rc != 0 or not done.exists():
            raise RunError(f'{cmd[0]} failed (exit {rc}); see {log}')

    def truth(self) -> Path:
        """Ground truth: ``--episodes`` recorded + ``--test-starts`` held-out trajectories (test split)."""
        a = self.args
        path = self.out / 'truth.npz'
        n = a.episodes + a.test_starts
        steps = int(round(a.seconds * 100))
        cmd = ['training.generate', '--scenario', 'flock2d', '--trajectories', str(n), '--train']
        cmd += [str(a.episodes), '--steps', str(steps), '--seed', str(a.seed), '--no-progress']
        self.run(cmd + ['--out', str(path.resolve())], self.out / 'generate.log', path)
        return path

    def case(self, truth: Path, noise_mm: float, rate: float) -> None:
        from knode_swarm_ros.core import load_trajectories

        a = self.args
        d = self.out / case_name(noise_mm, rate)
        bags = d / 'bags'
        data = d / 'data.npz'
        if not data.exists():
            bags.mkdir(parents=True, exist_ok=True)
            states = load_trajectories(truth).states
            dt = 0.01
            for e in range(a.episodes):
                bag = bags / f'ep{e:02d}.mcap'
                if bag.exists():
                    continue
                occ = (e % 10, 0.35 * a.seconds, 0.4) if e % 4 == 1 else None
                mocap = MocapNoise(rate=rate, noise=noise_mm * 1e-3, occlusion=occ)
                rng = np.random.default_rng([a.seed, e, int(noise_mm * 1000), int(rate)])
                tmp = bags / f'.ep{e:02d}.mcap'
                tmp.unlink(missing_ok=True)
                write_mocap_bag(tmp, states[e], dt, mocap, rng)
                tmp.rename(bag)
            names = [str(bags / f'ep{e:02d}.mcap') for e in range(a.episodes)]
            cmd = ['training.import_bag'] + names + ['--scenario', 'flock2d', '--topics', TOPICS]
            self.run(cmd + ['--rate', '100', '--out', str(data)], d / 'import.log', data)
        estimate = estimated_noise(data)
        done = {(r['case'], r['objective']) for r in self.rows()}
        for objective in a.objectives:
            if (d.name, objective) in done:
                self.log(f'{d.name} {objective}: done, skipped')
                continue
            run = d / objective
            # the configs hold out 8 validation trajectories, which count episodes here: hold out
            # data.val_fraction (a fifth) of them instead, as config/train_recorded.yaml does
            sets = [
                'data.val_trajectories=null',
                f'training.max_minutes={a.max_minutes}',
                'training.threads=1',
            ]
            sets += list(a.set or [])
            if objective == 'multi_step':
                sets.append(f'multistep.init={d / "one_step"}')
                if not (d / 'one_step' / 'policy.pt').exists():
                    raise KnodeError(f'{d.name}: multi_step fine-tunes the one_step run; list one_step first')
            cmd = ['training.train', '--config', CONFIGS[objective], '--data', str(data), '--out', str(run)]
            cmd += [x for s in sets for x in ('--set', s)] + ['--no-progress']
            if run.exists() and not (run / 'policy.pt').exists():  # a killed training: start it again
                cmd.append('--overwrite')
            load0, t0 = os.getloadavg()[0], time.time()
            self.run(cmd, d / f'train_{objective}.log', run / 'policy.pt')
            minutes = (time.time() - t0) / 60
            ev = d / f'eval_{objective}'
            cmd = ['training.evaluate', '--policy', str(run / 'policy.pt'), '--data', str(truth)]
            cmd += ['--trajectories', str(a.test_starts), '--out', str(ev)]
            self.run(cmd, d / f'eval_{objective}.log', ev / 'results.json')
            final = json.loads((ev / 'results.json').read_text())['final']
            row = {
                'case': d.name,
                'noise_mm': noise_mm,
                'rate_hz': rate,
                'objective': objective,
                'noise_estimate_mm': estimate,
                'final': {
                    k: final[k] for k in ('avd_final', 'amd_final', 'truth_amd_final', 'truth_avd_final')
                },
                'train_minutes': round(minutes, 1),
                'load': [round(load0, 1), round(os.getloadavg()[0], 1)],
                'date': time.strftime('%Y-%m-%d %H:%M'),
            }
            with open(self.rows_path, 'a') as f:
                f.write(json.dumps(row) + '\n')
            self.log(f'{d.name} {objective}: {row_text(row)}')
            (self.out / 'summary.md').write_text(summary(self.rows()))
            figure(self.rows(), self.out / 'noise_study.png')


def estimated_noise(data: Path) -> Optional[float]:
    """The importer's noise estimate (mm), mean over the episodes of ``data``."""
    from knode_swarm_ros.core import load_trajectories

    meta = load_trajectories(data).meta or {}
    found = [s['noise']['noise_std'] for s in meta.get('sources', []) if 'noise' in s]
    if 'noise' in meta:
        found.append(meta['noise']['noise_std'])
    return round(float(np.mean(found)) * 1e3, 3) if found else None


def row_text(row: Dict[str, Any]) -> str:
    f = row['final']
    amd_rel = f['amd_final']['mean'] / f['truth_amd_final']['mean'] - 1
    return (
        f'avd {f["avd_final"]["mean"]:.4f} (std {f["avd_final"]["std"]:.4f}), amd {f["amd_final"]["mean"]:.3f} '
        f'vs truth {f["truth_amd_final"]["mean"]:.3f} ({100 * amd_rel:+.1f} %), noise estimate '
        f'{row["noise_estimate_mm"]} mm, {row["train_minutes"]} min, load {row["load"][0]}-{row["load"][1]}'
    )


def summary(rows: List[Dict[str, Any]]) -> str:
    """Markdown table of all rows (final metrics over the clean held-out starts)."""
    lines = [
        '| noise (mm) | rate (Hz) | objective | estimate (mm) | avd final (mean ± std) | amd final | '
        'amd truth | amd error | train min | load |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for r in sorted(rows, key=lambda r: (r['rate_hz'], r['noise_mm'], r['objective'])):
        f = r['final']
        rel = f['amd_final']['mean'] / f['truth_amd_final']['mean'] - 1
        lines.append(
            f'| {r["noise_mm"]:g} | {r["rate_hz"]:g} | {r["objective"]} | {r["noise_estimate_mm"]} | '
            f'{f["avd_final"]["mean"]:.4f} ± {f["avd_final"]["std"]:.4f} | {f["amd_final"]["mean"]:.3f} | '
            f'{f["truth_amd_final"]["mean"]:.3f} | {100 * rel:+.1f} % | {r["train_minutes"]} | '
            f'{r["load"][0]}-{r["load"][1]} |'
        )
    return '\n'.join(lines) + '\n'


def figure(rows: List[Dict[str, Any]], path: Path) -> None:
    """Final avd (mean and std over the held-out starts) and amd error against the noise, one line
    per (objective, rate); the truth's avd as a dotted line."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax_avd, ax_amd) = plt.subplots(1, 2, figsize=(10, 4))
    for key in sorted({(r['objective'], r['rate_hz']) for r in rows}):
        sel = sorted((r for r in rows if (r['objective'], r['rate_hz']) == key), key=lambda r: r['noise_mm'])
        x = [r['noise_mm'] for r in sel]
        f = [r['final'] for r in sel]
        label = f'{key[0]}, {key[1]:g} Hz'
        ax_avd.errorbar(
            x,
            [v['avd_final']['mean'] for v in f],
            [v['avd_final']['std'] for v in f],
            label=label,
            marker='o',
            capsize=3,
        )
        rel = [100 * (v['amd_final']['mean'] / v['truth_amd_final']['mean'] - 1) for v in f]
        ax_amd.plot(x, rel, marker='o', label=label)
    if rows:
        ax_avd.axhline(rows[0]['final']['truth_avd_final']['mean'], ls=':', c='k', label='truth')
    ax_avd.set(xlabel='position noise (mm)', ylabel='final avd (held-out starts)', yscale='log')
    ax_amd.set(xlabel='position noise (mm)', ylabel='final amd vs truth (%)')
    ax_amd.axhline(0, ls=':', c='k')
    ax_avd.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@cli('python -m training.studies.noise_study')
def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(
        prog='python -m training.studies.noise_study', description=__doc__.split('\n\n')[0]
    )
    p.add_argument('--out', required=True, help='study directory (resumable)')
    p.add_argument('--noise', type=float, nargs='+', default=[0, 0.5, 2, 5, 10], help='noise std, mm')
    p.add_argument('--rates', type=float, nargs='+', default=[30, 60, 120], help='mocap rates, Hz')
    p.add_argument(
        '--objectives', nargs='+', choices=sorted(CONFIGS), default=['one_step'], help='trainings per case'
    )
    p.add_argument('--episodes', type=int, default=16, help='recorded episodes per case (one bag each)')
    p.add_argument('--seconds', type=float, default=20.0, help='length of an episode, s')
    p.add_argument('--test-starts', type=int, default=8, help='clean held-out starts for the evaluation')
    p.add_argument('--max-minutes', type=float, default=10.0, help='training.max_minutes of every training')
    p.add_argument('--seed', type=int, default=0, help='seed of the truth and the recordings')
    p.add_argument(
        '--set', action='append', metavar='SECTION.KEY=VALUE', help='override a config field (all)'
    )
    args = p.parse_args(argv)
    for name in ('episodes', 'test_starts', 'seconds', 'max_minutes'):
        if getattr(args, name) <= 0:
            raise KnodeError(f'--{name.replace("_", "-")} must be > 0, got {getattr(args, name):g}')
    if min(args.noise) < 0 or min(args.rates) <= 0:
        raise KnodeError(f'--noise must be >= 0 and --rates > 0, got {args.noise} and {args.rates}')
    study = Study(args)
    truth = study.truth()
    for rate in args.rates:
        for noise_mm in args.noise:
            study.case(truth, noise_mm, rate)
    study.log('study complete')
    return 0


if __name__ == '__main__':
    sys.exit(main())
