"""A policy trained by LeRobot, flown in the twin: `learn eval` on a `pretrained_model`
folder that `lerobot-train` writes (checkpoints/NNNNNN/pretrained_model):

    config.json                    the policy's config: "type" (act, diffusion, ...),
                                   input_features, output_features
    model.safetensors              its weights
    train_config.json              the run's config (the dataset it was trained on)
    policy_preprocessor.json, policy_postprocessor.json and their
    policy_*processor_step_*.safetensors   the processor pipelines (normalization stats)

Loaded as LeRobot's own evaluation loads one: the config's class from
`get_policy_class(type)`, `from_pretrained(folder)`, and the pre- and post-processor
pipelines from the folder (`make_pre_post_processors(config, pretrained_path=folder)`),
on the CPU. torch and lerobot are imported only here, only for such a folder (the
`learn-lerobot` extra). A folder whose type is `learn.linear_policy.TYPE` is the numpy
stand-in of the same interface and loads without torch.

Each step the policy is given what `export` gave it in training, for the whole batch at
once (`evaluate.fly_batch`):
- `observation.state` (B, 18): the twin env's state vector, which is the dataset's
  (`twin.gym_env.STATE_NAMES`, unnormalized: the preprocessor normalizes it with the
  dataset's stats, as in training);
- `observation.images.<camera>` (B, 3, H, W) float in [0, 1], RGB, for each camera among
  the policy's input features: the twin's render of that camera at the vehicle's true
  pose, through the path a recorded frame takes to the dataset (JPEG at the demos'
  quality, decoded and resized by area to the feature's size, `learn.images`);
- `task`: the dataset's task text;
at the dataset's rate: the batch is flown at `control_hz` = the dataset's fps, one
`select_action` per frame, each action held for a frame as the dataset's were. The
postprocessed action (roll, pitch, yaw, throttle, the dataset's `action`) is clipped to
[-1, 1] and flown as the four sticks.

The dataset (its fps and task text) is `dataset`, else the folder's train_config.json
`dataset.root` when that is here, else `export`'s defaults (`formats.DEFAULT_FPS`, the
scene's task text).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.evaluate import BatchAct
from fpv_station.learn.formats import DEFAULT_FPS
from fpv_station.learn.images import decode_fit
from fpv_station.learn.lerobot import read_meta

if TYPE_CHECKING:  # imported when a camera is first rendered (OpenCV)
    from fpv_station.twin.render import Renderer

CONFIG_FILE = "config.json"
TRAIN_CONFIG_FILE = "train_config.json"
STATE_KEY = "observation.state"
IMAGE_PREFIX = "observation.images."
ACTION_KEY = "action"
CAMERAS = ("front", "bottom")
# The JPEG quality twin frames are recorded at (`learn.demos.DemoConfig.jpeg_quality`).
JPEG_QUALITY = 80
EXTRA_HINT = "pip install 'fpv-station[learn-lerobot]'"


def policy_folder(path: Path) -> Path | None:
    """The `pretrained_model` folder `path` names: itself when it holds a config.json, or
    its `pretrained_model`, or `checkpoints/last/pretrained_model` (a checkpoint or the
    `--output_dir` of `lerobot-train`); None when it is none of these (a file)."""
    path = Path(path)
    for folder in (path, path / "pretrained_model", path / "checkpoints/last/pretrained_model"):
        if (folder / CONFIG_FILE).is_file():
            return folder
    return None


@dataclass(frozen=True)
class PolicyInputs:
    """What the policy reads and gives, from its config.json's features."""

    type: str
    state_dim: int
    images: dict[str, tuple[int, int]]  # camera -> (width, height)
    action_dim: int

    @classmethod
    def read(cls, folder: Path) -> PolicyInputs:
        path = Path(folder) / CONFIG_FILE
        try:
            config = json.loads(path.read_text())
            inputs, outputs = config["input_features"], config["output_features"]
            kind = str(config["type"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"'{path}' is not a LeRobot policy config ({exc})") from None
        images, state_dim = {}, 0
        for key, f in inputs.items():
            shape = [int(v) for v in f.get("shape", [])]
            if key == STATE_KEY:
                state_dim = shape[0]
            elif key.startswith(IMAGE_PREFIX) and len(shape) == 3:
                cam = key[len(IMAGE_PREFIX) :]
                if cam not in CAMERAS:
                    raise ValueError(
                        f"the policy reads camera '{cam}'; the twin has {', '.join(CAMERAS)}"
                    )
                images[cam] = (shape[2], shape[1])  # (C, H, W)
            else:
                raise ValueError(f"the policy reads '{key}', which the twin does not give")
        action = [int(v) for v in outputs.get(ACTION_KEY, {}).get("shape", [])]
        return cls(kind, state_dim, images, action[0] if action else 0)


@dataclass(frozen=True)
class DatasetFacts:
    """What the bridge needs of the training dataset: its rate and task text."""

    fps: float
    task: str
    task_id: int  # 0: unknown
    source: str  # where these came from, for the record


def dataset_facts(folder: Path, dataset: Path | None, scene: Scene, task_id: int) -> DatasetFacts:
    from fpv_station.learn.export import task_description

    root = Path(dataset) if dataset is not None else _trained_on(Path(folder))
    if root is not None:
        meta = read_meta(root)
        task = meta.tasks[0] if meta.tasks else task_description(scene, task_id)
        return DatasetFacts(float(meta.fps), task, meta.task_id, str(root))
    return DatasetFacts(
        float(DEFAULT_FPS), task_description(scene, task_id), 0, "export's defaults"
    )


def _trained_on(folder: Path) -> Path | None:
    """train_config.json's `dataset.root`, when it is a dataset on this machine."""
    try:
        root = json.loads((folder / TRAIN_CONFIG_FILE).read_text())["dataset"]["root"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if root and (Path(root) / "meta" / "info.json").is_file():
        return Path(root)
    return None


class LeRobotPolicy:
    """A `pretrained_model` folder as `evaluate.BatchPolicy`: `learn eval` flies it."""

    def __init__(
        self,
        folder: Path,
        task_id: int,
        dataset: Path | None = None,
        scene: Scene | None = None,
    ) -> None:
        self.folder = policy_folder(folder) or Path(folder)
        self.scene = scene or load_scene()
        self.inputs = PolicyInputs.read(self.folder)
        if self.inputs.state_dim not in (0, 18) or self.inputs.action_dim != 4:
            raise ValueError(
                f"'{self.folder}' maps a state of {self.inputs.state_dim} to an action of "
                f"{self.inputs.action_dim}; the twin gives 18 (observation.state of "
                "`export`) and takes 4 sticks"
            )
        self.facts = dataset_facts(self.folder, dataset, self.scene, task_id)
        self.task_id = self.facts.task_id
        self.control_hz = self.facts.fps
        self.name = f"LeRobot {self.inputs.type}"
        self._runtime = _load(self.folder, self.inputs.type)
        self._renderer: Renderer | None = None

    def batch_act(self, episodes: int) -> BatchAct:
        """A fresh episode for every vehicle: the policy's state (action queues) reset."""
        self._runtime.reset()

        def act(obs: np.ndarray, info: dict[str, Any]) -> np.ndarray:
            batch: dict[str, Any] = {STATE_KEY: np.asarray(obs, np.float32)}
            for cam, size in self.inputs.images.items():
                batch[IMAGE_PREFIX + cam] = self.images(cam, size, info["pose"], info["done"])
            batch["task"] = [self.facts.task] * len(obs)
            return np.clip(self._runtime.act(batch), -1.0, 1.0)

        return act

    def images(self, camera: str, size: tuple[int, int], pose, done: np.ndarray) -> np.ndarray:
        """(B, 3, H, W) float32 RGB in [0, 1]: vehicle k's `camera` as the dataset holds
        it (black for an ended vehicle, whose action is not flown)."""
        w, h = size
        out = np.zeros((len(done), 3, h, w), np.float32)
        if self._renderer is None:
            from fpv_station.twin.render import Renderer

            self._renderer = Renderer(self.scene)
        for k in np.flatnonzero(~done):
            bgr = self._renderer.render(camera, pose(int(k)))
            ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if not ok:
                raise RuntimeError("JPEG encoding of a twin frame failed")
            rgb = decode_fit(jpeg.tobytes(), size)[..., ::-1]
            out[k] = rgb.transpose(2, 0, 1) / np.float32(255.0)
        return out


class _NumpyRuntime:
    """The numpy stand-in (`learn.linear_policy`): the same calls, no torch."""

    def __init__(self, folder: Path) -> None:
        from fpv_station.learn.linear_policy import LinearPolicy

        self.policy = LinearPolicy.from_pretrained(folder)

    def reset(self) -> None:
        self.policy.reset()

    def act(self, batch: dict[str, Any]) -> np.ndarray:
        p = self.policy
        return np.asarray(p.postprocess(p.select_action(p.preprocess(batch))), np.float32)


class _TorchRuntime:
    """A LeRobot policy with its processors, loaded as `lerobot-eval` loads one, on the
    CPU."""

    def __init__(self, folder: Path) -> None:
        try:
            import torch
            from lerobot.configs.policies import PreTrainedConfig
            from lerobot.policies.factory import get_policy_class, make_pre_post_processors
        except ImportError as exc:
            raise ImportError(
                f"'{folder}' is a LeRobot policy; flying it needs torch and lerobot ({exc}): "
                f"{EXTRA_HINT}"
            ) from None
        self.torch = torch
        config = PreTrainedConfig.from_pretrained(str(folder))
        config.device = "cpu"
        self.policy = get_policy_class(config.type).from_pretrained(str(folder), config=config)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            config,
            pretrained_path=str(folder),
            preprocessor_overrides={"device_processor": {"device": "cpu"}},
        )

    def reset(self) -> None:
        self.policy.reset()
        for pipeline in (self.preprocessor, self.postprocessor):
            pipeline.reset()

    def act(self, batch: dict[str, Any]) -> np.ndarray:
        torch = self.torch
        tensors = {
            k: torch.from_numpy(v) if isinstance(v, np.ndarray) else v for k, v in batch.items()
        }
        with torch.inference_mode():
            action = self.policy.select_action(self.preprocessor(tensors))
            action = self.postprocessor(action)
        return action.to("cpu").numpy().astype(np.float32)


def _load(folder: Path, kind: str) -> _NumpyRuntime | _TorchRuntime:
    from fpv_station.learn.linear_policy import TYPE

    return _NumpyRuntime(folder) if kind == TYPE else _TorchRuntime(folder)
