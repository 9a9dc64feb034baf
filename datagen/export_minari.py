"""`smgen export --format minari`: a dataset as a Minari dataset (offline RL's format), written by
the `minari` package itself (create_dataset_from_buffers, then update_dataset_from_buffer per lake
block: memory bounded by a block), so `minari.load_dataset` opens it with its own reader.

How a lake dataset maps (docs/FORMAT.md): an episode of a walk is a Minari episode. A dataset of
independent transitions is refused: it would be one one-step episode per transition, and Minari's
arrow storage keeps a folder per episode (measured: 2000 transitions took 2 min 15 s and 24 MB).
Observations are a Dict of `motor` (m, float32 in [-1, 1]) and `sensor` (s, as stored: float32, or uint8 frames kept
lossless: no JPEG); the action of a step is the motor state it moves to (m_t1). Rewards are 0, no
step terminates, and the last step of each episode is truncated (its length is the dataset's).
The privileged ground truth a learner must not see is in the infos: `position` (p) and `shift`.

--out is a Minari datasets root (what MINARI_DATASETS_PATH names); the dataset inside it is
`smspace/<dataset id>-v0`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.datagen.export_folder import built_folder
from smspace.lake.dataset import Dataset
from smspace.lake.shards import Block
from smspace.lake.transitions import Transitions

NAMESPACE = "smspace"
ROOT_VARIABLE = "MINARI_DATASETS_PATH"


def minari_id(dataset_id: str) -> str:
    return f"{NAMESPACE}/{dataset_id}-v0"


def spaces_of(ds: Dataset):
    """(observation space, action space): a motor Box in [-1, 1]; the sensor's own Box (bytes for
    frames; unbounded floats, whose range the manifest records, for vector sensors)."""
    from gymnasium import spaces

    m = ds.manifest
    motor = spaces.Box(-1.0, 1.0, (m.n_motor,), np.float32)
    shape = tuple(m.sensor_shape)
    if m.sensor_dtype == "uint8":
        sensor = spaces.Box(0, 255, shape, np.uint8)
    else:
        sensor = spaces.Box(-np.inf, np.inf, shape, np.float32)
    return spaces.Dict({"motor": motor, "sensor": sensor}), motor


def _episodes_of(block: Block) -> Iterator[tuple[slice, int]]:
    """(rows, episode id) of each episode in a block of a walk: its runs of one episode index."""
    n = len(block.transitions)
    if block.episode is None:
        raise SmspaceError(f"the block at transition {block.first_index} has no episode indices")
    cuts = np.flatnonzero(np.diff(block.episode)) + 1
    for start, end in zip([0, *cuts], [*cuts, n], strict=True):
        yield slice(int(start), int(end)), int(block.episode[start])


def episode_buffer(t: Transitions, episode_id: int):
    """One episode's steps as Minari's EpisodeBuffer: L steps, L + 1 observations."""
    from minari.data_collector.episode_buffer import EpisodeBuffer

    def chain(before: np.ndarray, after: np.ndarray) -> np.ndarray:
        return np.concatenate([before, after[-1:]])

    n = len(t)
    return EpisodeBuffer(
        id=episode_id,
        observations={"motor": chain(t.m_t, t.m_t1), "sensor": chain(t.s_t, t.s_t1)},
        actions=np.ascontiguousarray(t.m_t1),
        rewards=np.zeros(n, np.float64),
        terminations=np.zeros(n, bool),
        truncations=np.arange(n) == n - 1,
        infos={"position": chain(t.p_t, t.p_t1), "shift": chain(t.shift_t, t.shift_t1)},
    )


def _blocks(ds: Dataset, limit: int | None) -> Iterator[list]:
    """Buffers of whole episodes, one list per lake block; a limit keeps whole episodes only."""
    done = 0
    for block in ds.blocks():
        episodes = list(_episodes_of(block))
        buffers = []
        for rows, episode_id in episodes:
            size = rows.stop - rows.start
            if limit is not None and done + size > limit:
                break
            buffers.append(episode_buffer(block.transitions[rows], episode_id))
            done += size
        if buffers:
            yield buffers
        if limit is not None and (done >= limit or len(buffers) < len(episodes)):
            return


@contextmanager
def _root(path: Path) -> Iterator[None]:
    """minari finds its datasets through an environment variable: set for the duration only."""
    before = os.environ.get(ROOT_VARIABLE)
    os.environ[ROOT_VARIABLE] = str(path)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(ROOT_VARIABLE, None)
        else:
            os.environ[ROOT_VARIABLE] = before


def export_minari(ds: Dataset, out: Path, limit: int | None = None, overwrite: bool = False) -> int:
    import minari

    m = ds.manifest
    if ds.manifest.config.get("exploration") is None:
        raise SmspaceError(
            f"{m.dataset_id} is independent transitions, and Minari holds episodes (one folder each): "
            "generate walks (smgen generate --exploration walk), or export it --format hf or parquet"
        )
    observation_space, action_space = spaces_of(ds)
    with built_folder(ds, out, overwrite, "minari") as folder, _root(folder), warnings.catch_warnings():
        # minari advises on fields smspace has no value for (a code link, an e-mail, an env spec)
        warnings.filterwarnings("ignore", category=UserWarning, module=r"minari\.")
        count, dataset = 0, None
        for buffers in _blocks(ds, limit):
            count += sum(len(b.actions) for b in buffers)
            if dataset is None:
                dataset = minari.create_dataset_from_buffers(
                    minari_id(m.dataset_id), buffers, observation_space=observation_space,
                    action_space=action_space, algorithm_name=f"smspace ({m.exploration_words})",
                    author="smspace", description=description(ds), data_format="arrow", jpeg_encoding=False,
                )  # fmt: skip
            else:
                dataset.update_dataset_from_buffer(buffers)
        if dataset is None:
            raise SmspaceError(f"{m.dataset_id}: no whole episode within --limit {limit}")
    return count


def description(ds: Dataset) -> str:
    m = ds.manifest
    return (
        f"smspace dataset {m.dataset_id}: the {m.setup} setup in mode {m.mode}, world seed {m.world_seed}, "
        f"{m.exploration_words}; config hash {m.config_hash}. Observations: motor (m) and sensor (s); the "
        "action is the motor state moved to; infos hold the privileged sensor position and environment "
        "shift. The smspace manifest is smspace.json at the root of this export."
    )


def read_minari(out: Path, dataset_id: str) -> tuple[list[int], list[int], Transitions]:
    """An export read back by `minari.load_dataset` (the inverse of export_minari): the episode
    ids, their lengths and the transitions in episode order."""
    import minari

    with _root(Path(out)):
        dataset = minari.load_dataset(minari_id(dataset_id))
        ids, lengths, parts = [], [], []
        for episode in dataset.iterate_episodes():
            obs, infos = episode.observations, episode.infos
            ids.append(int(episode.id))
            lengths.append(len(episode))
            parts.append(Transitions(
                m_t=obs["motor"][:-1], m_t1=obs["motor"][1:], s_t=obs["sensor"][:-1], s_t1=obs["sensor"][1:],
                p_t=infos["position"][:-1], p_t1=infos["position"][1:],
                shift_t=infos["shift"][:-1], shift_t1=infos["shift"][1:],
            ))  # fmt: skip
            if not np.array_equal(episode.actions, obs["motor"][1:]):
                raise SmspaceError(f"episode {episode.id}: its actions are not the motor states it moved to")
    return ids, lengths, Transitions.concat(parts)
