"""A linear policy in numpy that is saved, loaded and called as a LeRobot policy is: a
stand-in with no torch, so that the LeRobot bridge (`learn.lerobot_policy`) runs whole
where torch is not installed (CI), on a folder of the same layout as `lerobot-train`'s
`pretrained_model`:

    config.json                      "type" (`TYPE`), input_features, output_features,
                                     normalization_mapping, as a LeRobot policy config
    model.safetensors                the weights (safetensors' numpy API)
    policy_preprocessor.json         LeRobot's processor pipeline: one normalizer_processor
    policy_preprocessor_step_0_normalizer_processor.safetensors     "observation.state.mean", ".std"
    policy_postprocessor.json        one unnormalizer_processor
    policy_postprocessor_step_0_unnormalizer_processor.safetensors  "action.mean", ".std"

The model: normalized action = `state_weight` @ normalized state + for each camera
`image_weight.<key>` @ the image's mean red, green, blue + `bias`. `fit` takes the
weights from a LeRobot dataset of `export` by least squares on the state (its image
weights are zero). Normalization is LeRobot's MEAN_STD with the dataset's stats.json.
It is a test vehicle for the bridge's path, not a policy that flies the tasks.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from fpv_station.learn.bc import _matrix

TYPE = "fpv_linear"
STATE = "observation.state"
ACTION = "action"
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
PREPROCESSOR = "policy_preprocessor"
POSTPROCESSOR = "policy_postprocessor"
EPS = 1e-8  # LeRobot's normalizer eps


@dataclass
class LinearPolicy:
    state_weight: NDArray[np.float32]  # (action_dim, state_dim)
    bias: NDArray[np.float32]  # (action_dim,)
    state_mean: NDArray[np.float32]
    state_std: NDArray[np.float32]
    action_mean: NDArray[np.float32]
    action_std: NDArray[np.float32]
    # camera image key -> (action_dim, 3) weights on its mean RGB in [0, 1]
    image_weight: dict[str, NDArray[np.float32]] = field(default_factory=dict)
    image_sizes: dict[str, tuple[int, int]] = field(default_factory=dict)  # key -> (w, h)

    # ------------------------------------------------------------ LeRobot's contract

    def reset(self) -> None:
        """No state between calls (LeRobot policies clear their action queues here)."""

    def select_action(self, batch: dict[str, Any]) -> NDArray[np.float32]:
        """(B, action_dim) normalized actions from a normalized batch."""
        out = batch[STATE] @ self.state_weight.T + self.bias
        for key, w in self.image_weight.items():
            out = out + batch[key].mean(axis=(2, 3)) @ w.T
        return out.astype(np.float32)

    def preprocess(self, batch: dict[str, Any]) -> dict[str, Any]:
        return {**batch, STATE: (batch[STATE] - self.state_mean) / (self.state_std + EPS)}

    def postprocess(self, action: np.ndarray) -> np.ndarray:
        return action * (self.action_std + EPS) + self.action_mean

    # ------------------------------------------------------------ training

    @classmethod
    def fit(cls, dataset: Path, ridge: float = 1e-3) -> LinearPolicy:
        """Least squares from the normalized state to the normalized action over every
        frame of a LeRobot dataset from `export`, with its stats.json's mean and std."""
        root = Path(dataset)
        info = json.loads((root / "meta" / "info.json").read_text())
        stats = json.loads((root / "meta" / "stats.json").read_text())
        files = sorted((root / "data").glob("*/*.parquet"))
        tables = [pq.read_table(f, columns=[STATE, ACTION]) for f in files]
        if not tables:
            raise ValueError(f"'{root}' is not a LeRobot dataset (no data/*/*.parquet)")
        s = np.concatenate([_matrix(t.column(STATE)) for t in tables])
        a = np.concatenate([_matrix(t.column(ACTION)) for t in tables])
        sm, ss = (np.asarray(stats[STATE][k], np.float32) for k in ("mean", "std"))
        am, asd = (np.asarray(stats[ACTION][k], np.float32) for k in ("mean", "std"))
        x = np.column_stack([(s - sm) / (ss + EPS), np.ones(len(s))])
        y = (a - am) / (asd + EPS)
        w = np.linalg.solve(x.T @ x + ridge * np.eye(x.shape[1]), x.T @ y).T
        sizes = {
            k: (int(f["shape"][1]), int(f["shape"][0]))  # info.json: (H, W, C)
            for k, f in info["features"].items()
            if f["dtype"] in ("video", "image")
        }
        return cls(
            state_weight=w[:, :-1].astype(np.float32),
            bias=w[:, -1].astype(np.float32),
            state_mean=sm,
            state_std=ss,
            action_mean=am,
            action_std=asd,
            image_weight={k: np.zeros((a.shape[1], 3), np.float32) for k in sizes},
            image_sizes=sizes,
        )

    # ------------------------------------------------------------ files

    def config(self) -> dict[str, Any]:
        inputs: dict[str, Any] = {STATE: {"type": "STATE", "shape": [len(self.state_mean)]}}
        for key, (w, h) in self.image_sizes.items():
            inputs[key] = {"type": "VISUAL", "shape": [3, h, w]}
        return {
            "type": TYPE,
            "input_features": inputs,
            "output_features": {ACTION: {"type": "ACTION", "shape": [len(self.bias)]}},
            "normalization_mapping": {"STATE": "MEAN_STD", "ACTION": "MEAN_STD"},
            "device": "cpu",
        }

    def save_pretrained(self, folder: Path) -> Path:
        from safetensors.numpy import save_file

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / CONFIG_FILE).write_text(json.dumps(self.config(), indent=2))
        weights = {"state_weight": self.state_weight, "bias": self.bias}
        weights |= {f"image_weight.{k}": w for k, w in self.image_weight.items()}
        save_file(
            {k: np.ascontiguousarray(v, np.float32) for k, v in weights.items()},
            str(folder / WEIGHTS_FILE),
        )
        stats = {
            PREPROCESSOR: ("normalizer_processor", STATE, self.state_mean, self.state_std),
            POSTPROCESSOR: ("unnormalizer_processor", ACTION, self.action_mean, self.action_std),
        }
        for name, (step, key, mean, std) in stats.items():
            state_file = f"{name}_step_0_{step}.safetensors"
            ftype = "STATE" if key == STATE else "ACTION"
            pipeline = {
                "name": name,
                "steps": [
                    {
                        "registry_name": step,
                        "config": {
                            "eps": EPS,
                            "features": {key: {"type": ftype, "shape": [len(mean)]}},
                            "norm_map": {ftype: "MEAN_STD"},
                        },
                        "state_file": state_file,
                    }
                ],
            }
            (folder / f"{name}.json").write_text(json.dumps(pipeline, indent=2))
            save_file(
                {
                    f"{key}.mean": np.asarray(mean, np.float32),
                    f"{key}.std": np.asarray(std, np.float32),
                },
                str(folder / state_file),
            )
        return folder

    @classmethod
    def from_pretrained(cls, folder: Path) -> LinearPolicy:
        from safetensors.numpy import load_file

        folder = Path(folder)
        config = json.loads((folder / CONFIG_FILE).read_text())
        if config.get("type") != TYPE:
            raise ValueError(f"'{folder}' holds a '{config.get('type')}' policy, not {TYPE}")
        w = load_file(str(folder / WEIGHTS_FILE))
        pre = _normalizer_stats(folder, PREPROCESSOR, STATE)
        post = _normalizer_stats(folder, POSTPROCESSOR, ACTION)
        sizes = {
            k: (int(f["shape"][2]), int(f["shape"][1]))  # (C, H, W)
            for k, f in config["input_features"].items()
            if f["type"] == "VISUAL"
        }
        return cls(
            state_weight=w["state_weight"],
            bias=w["bias"],
            state_mean=pre["mean"],
            state_std=pre["std"],
            action_mean=post["mean"],
            action_std=post["std"],
            image_weight={k: w[f"image_weight.{k}"] for k in sizes},
            image_sizes=sizes,
        )


def _normalizer_stats(folder: Path, pipeline: str, key: str) -> dict[str, np.ndarray]:
    """The mean and std of `key` from the pipeline's (un)normalizer step (MEAN_STD only)."""
    from safetensors.numpy import load_file

    spec = json.loads((folder / f"{pipeline}.json").read_text())
    for step in spec.get("steps", []):
        if step.get("registry_name") in ("normalizer_processor", "unnormalizer_processor"):
            if set(step["config"].get("norm_map", {}).values()) - {"MEAN_STD", "IDENTITY"}:
                raise ValueError(f"{pipeline}: only MEAN_STD normalization is read here")
            state = load_file(str(folder / step["state_file"]))
            return {s: state[f"{key}.{s}"] for s in ("mean", "std")}
    raise ValueError(f"'{folder / pipeline}.json' has no normalizer step for {key}")


__all__ = ["TYPE", "LinearPolicy"]
