"""A LeRobot policy trained by `lerobot-train` on twin demonstrations, flown by `learn eval`.

    python benchmarks/lerobot_policy.py [--demos 20] [--steps 200] [--batch-size 8]
        [--policy act] [--image-size 96x72] [--episodes 20] [--work DIR]

Needs the `learn-lerobot` extra (torch, lerobot; `lerobot-train` beside this Python).
The documented commands, in order: `fpv-station demos --task 1 --count N --cameras`,
`fpv-station export --format lerobot --image-size WxH` (both cameras, 10 fps),
`lerobot-train` (ACT or diffusion, on the CPU, `--steps` steps, no pretrained backbone:
nothing is fetched from a hub), then `fpv-station learn eval` on its last
`pretrained_model` with the scripted pilot and random rows (one batch, seed 1000).
Prints the table, then the policy's success, hover distance, height deviation, the
training time and the machine's load. With `--work DIR` the steps whose output is
already there are skipped (demos, dataset, training), so a run can be resumed.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.learning_pipeline import export_lerobot, fly_demos, run_cli  # noqa: E402

REPO_ID = "fpv-station/demonstrations"


def load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.1f} / {five:.1f} / {fifteen:.1f}"


def lerobot_train() -> str:
    exe = Path(sys.executable).with_name("lerobot-train")
    found = str(exe) if exe.exists() else shutil.which("lerobot-train")
    if not found:
        raise SystemExit("lerobot-train not found: pip install 'fpv-station[learn-lerobot]'")
    return found


def train_argv(args: argparse.Namespace, dataset: Path, out: Path) -> list[str]:
    argv = [
        lerobot_train(),
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={dataset}",
        "--dataset.video_backend=pyav",
        f"--policy.type={args.policy}",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--output_dir={out}",
        f"--steps={args.steps}",
        f"--batch_size={args.batch_size}",
        f"--save_freq={args.steps}",
        "--log_freq=10",
        "--num_workers=0",
        "--wandb.enable=false",
        "--seed=0",
    ]
    if args.policy == "act":
        # No ImageNet weights (nothing can be fetched here); short action chunks for
        # the few hundred steps a CPU run affords.
        argv += [
            "--policy.pretrained_backbone_weights=null",
            f"--policy.chunk_size={args.chunk}",
            f"--policy.n_action_steps={args.chunk}",
        ]
    elif args.policy == "diffusion":
        w, h = (int(v) for v in args.image_size.split("x"))
        argv += [f"--policy.crop_shape=[{h - 8},{w - 8}]", "--policy.num_inference_steps=10"]
    return argv


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--demos", type=int, default=20, help="task-1 demonstrations")
    ap.add_argument("--policy", default="act", choices=("act", "diffusion"))
    ap.add_argument("--steps", type=int, default=200, help="training steps")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--chunk", type=int, default=10, help="ACT's chunk size (frames)")
    ap.add_argument("--image-size", default="96x72", help="camera images in the dataset")
    ap.add_argument("--episodes", type=int, default=20, help="episodes flown per row")
    ap.add_argument("--work", type=Path, help="keep (and reuse) the demos, dataset, training")
    args = ap.parse_args()
    started = f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {load()}"
    with contextlib.ExitStack() as stack:
        if args.work is None:
            work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="lerobot-")))
        else:
            work = args.work
            work.mkdir(parents=True, exist_ok=True)
        demos, dataset, out = work / "demos", work / "dataset", work / "train"
        if not demos.is_dir():
            fly_demos(demos, 1, args.demos, ["--cameras"])
        sessions = sorted(str(p) for p in demos.iterdir() if p.is_dir())[: args.demos]
        if not dataset.is_dir():
            export_lerobot(sessions, dataset, ["--task", "1", "--image-size", args.image_size])
        model = out / "checkpoints" / "last" / "pretrained_model"
        train_s = None
        if not model.is_dir():
            t0 = time.perf_counter()
            subprocess.run(train_argv(args, dataset, out), check=True)
            train_s = time.perf_counter() - t0
            print(f"trained in {train_s:.0f} s, {load()}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        argv = ["learn", "eval", str(model), "--task", "1", "--episodes", str(args.episodes)]
        table = run_cli([*argv, "--seed", "1000", "--dataset", str(dataset)])
        eval_s = time.perf_counter() - t0
    print(table)
    row = next(line for line in table.splitlines() if line.startswith("| LeRobot"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    trained = f"{train_s:.0f} s" if train_s is not None else "earlier (reused)"
    print(
        f"{cells[0]}: {args.demos} task-1 demonstrations, {args.image_size} images, "
        f"{args.steps} steps at batch {args.batch_size}\n"
        f"success {cells[3]}, hover distance {cells[5]} m, height deviation {cells[6]} m\n"
        f"training time {trained}, evaluation {eval_s:.0f} s\n"
        f"{platform.machine()}, {os.cpu_count()} cores; started {started}; ended {load()}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
