"""Exploration as an agent really moves: episodes of a bounded random walk in motor space.

The paper's datasets are independent transitions, a teleport between any two. A walk instead
chains them: within an episode, the motor state a step ends in is the one the next step starts
from, and so are the sensor position, the environment's shift and the sensation. Between episodes
the agent starts afresh (uniformly) and, in MME and MEM, the environment moves (the paper's
condition II: the environment changes only while the agent does not act in MME); in MEM it also
moves at every step, as today's MEM transitions move it between m_t and m_t1.

Each time point is sensed once (a transition's s_t1 *is* the next one's s_t), so a walk of L steps
costs L + 1 sensations, not 2 L.

A world walks if it has `walk_motors(rng, episodes, length, step)`: the grid on its lattice of
motor levels (`lattice_walk`), the arm and any world with `positions(m)` in its continuous motor
space (`continuous_walk`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smspace.common.errors import SmspaceError
from smspace.lake.exploration import MAX_LENGTH
from smspace.lake.transitions import Transitions

MAX_EPISODES = 1 << 24


@dataclass(frozen=True)
class Walks:
    """Transitions in episode order, with each one's episode index and step index in it."""

    transitions: Transitions
    episode: np.ndarray  # (n,) int64
    step: np.ndarray  # (n,) int64, 0 .. length - 1 within each episode


def reflect(x: np.ndarray, low: float, high: float) -> np.ndarray:
    """x folded into [low, high] as a mirror would (a walk that overshoots a bound bounces back)."""
    width = high - low
    y = np.mod(x - low, 2 * width)
    return low + np.where(y > width, 2 * width - y, y)


def _check_shape(episodes: int, length: int) -> None:
    if not 1 <= episodes <= MAX_EPISODES:
        raise SmspaceError(f"episodes: {episodes}; between 1 and {MAX_EPISODES}")
    if not 1 <= length <= MAX_LENGTH:
        raise SmspaceError(f"episode length: {length} steps; between 1 and {MAX_LENGTH}")


def continuous_walk(rng: np.random.Generator, n_motor: int, episodes: int, length: int, step: float) -> np.ndarray:
    """(episodes, length + 1, n_motor) motor states in [-1, 1]: a uniform start, then Gaussian
    steps of standard deviation `step` per motor, reflected at the bounds."""
    _check_shape(episodes, length)
    if not 0 < step <= 2:
        raise SmspaceError(f"walk step: {step}; a standard deviation in (0, 2] of the motor range [-1, 1]")
    start = rng.uniform(-1.0, 1.0, (episodes, 1, n_motor))
    moves = rng.normal(0.0, step, (episodes, length, n_motor))
    return reflect(np.concatenate([start, start + np.cumsum(moves, axis=1)], axis=1), -1.0, 1.0)


def lattice_walk(
    rng: np.random.Generator, n_motor: int, levels: int, episodes: int, length: int, step: int
) -> np.ndarray:
    """(episodes, length + 1) indices into the lattice of `levels`**n_motor motor states (first
    motor slowest, as grid.level_grid orders them): a uniform start, then each motor moves by a
    uniform integer in [-step, step] levels, reflected at the lattice's ends."""
    _check_shape(episodes, length)
    if not (isinstance(step, int) and 1 <= step < levels):
        raise SmspaceError(f"walk step: {step!r}; a whole number of levels from 1 to {levels - 1}")
    start = rng.integers(0, levels, (episodes, 1, n_motor))
    moves = rng.integers(-step, step + 1, (episodes, length, n_motor))
    level = np.concatenate([start, start + np.cumsum(moves, axis=1)], axis=1)
    level = np.rint(reflect(level.astype(np.float64), 0.0, levels - 1.0)).astype(np.int64)
    weights = levels ** np.arange(n_motor - 1, -1, -1)
    return level @ weights


def walk_shifts(world, mode: str, rng: np.random.Generator, episodes: int, length: int) -> np.ndarray:
    """(episodes, length + 1, 2): fixed in MM, one per episode in MME, one per time point in MEM."""
    if mode == "MM":
        return np.broadcast_to(np.asarray(world.static_shift, np.float64), (episodes, length + 1, 2)).copy()
    if mode == "MME":
        return np.repeat(world.sample_shifts(rng, episodes)[:, None, :], length + 1, axis=1)
    if mode == "MEM":
        return world.sample_shifts(rng, episodes * (length + 1)).reshape(episodes, length + 1, 2)
    raise SmspaceError(f"unknown mode {mode!r}")


def draw_walks(world, mode: str, rng: np.random.Generator, episodes: int, length: int, step: float) -> Walks:
    """`episodes` walks of `length` steps each, as episodes × length transitions."""
    walk_motors = getattr(world, "walk_motors", None)
    if walk_motors is None:
        raise SmspaceError(f"{type(world).__name__} cannot walk: it has no walk_motors(rng, episodes, length, step)")
    m, p = walk_motors(rng, episodes, length, step)
    shift = walk_shifts(world, mode, rng, episodes, length)
    points = episodes * (length + 1)
    s = world.sense(p.reshape(points, -1), shift.reshape(points, 2))
    s = s.reshape(episodes, length + 1, *s.shape[1:])
    f32 = np.float32

    def now(x: np.ndarray, dtype=None) -> np.ndarray:
        return np.ascontiguousarray(x[:, :-1].reshape(episodes * length, *x.shape[2:]), dtype=dtype)

    def next_(x: np.ndarray, dtype=None) -> np.ndarray:
        return np.ascontiguousarray(x[:, 1:].reshape(episodes * length, *x.shape[2:]), dtype=dtype)

    transitions = Transitions(
        m_t=now(m, f32), m_t1=next_(m, f32), s_t=now(s), s_t1=next_(s),
        p_t=now(p, f32), p_t1=next_(p, f32), shift_t=now(shift, f32), shift_t1=next_(shift, f32),
    )  # fmt: skip
    episode = np.repeat(np.arange(episodes, dtype=np.int64), length)
    step_index = np.tile(np.arange(length, dtype=np.int64), episodes)
    return Walks(transitions, episode, step_index)
