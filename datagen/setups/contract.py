"""The contract every setup's world is held to (docs/API.md, "Plugins"), ours and a plugin's alike:
what it declares (motors, sensor shape and dtype) is what it draws, motors lie in [-1, 1], and
every value is finite. `check_world` runs a probe batch of every mode before anything is written;
`check_block` and `check_regular` run on every part before it is stored, so a NaN drawn late is
refused before the dataset could be committed. Broken, it is one line naming the setup, the world
and what it gave.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smspace.common import plugins
from smspace.common.errors import SmspaceError
from smspace.datagen.setups.base import Setup, World, draw_transitions
from smspace.lake.manifest import MAX_REGULAR
from smspace.lake.transitions import MODES, Transitions

SENSOR_DTYPES = ("float32", "uint8")  # what a shard stores (lake/shards.py)
PROBE = 64  # transitions per mode in the probe batch
PROBE_STREAM = 7  # the probe's own seed stream (SeedSequence spawn key): the data's are (0,) and (1, …)


def declared(setup: Setup, world: World, where: str) -> tuple[int, tuple[int, ...], np.dtype]:
    """(N_m, sensor shape, sensor dtype) as the world declares them, checked against the setup."""
    try:
        n_motor = int(world.n_motor)
        shape = tuple(int(d) for d in world.sensor_shape)
        dtype = np.dtype(world.sensor_dtype)
    except (AttributeError, TypeError, ValueError) as e:
        raise SmspaceError(f"{where}: n_motor, sensor_shape and sensor_dtype must be declared ({e})") from None
    if n_motor != setup.n_motor:
        raise SmspaceError(f"{where}: the world has {n_motor} motors, its Setup declares n_motor={setup.n_motor}")
    if not shape or any(d < 1 for d in shape):
        raise SmspaceError(f"{where}: sensor_shape {shape} must be one or more positive sizes")
    if dtype.name not in SENSOR_DTYPES:
        raise SmspaceError(f"{where}: sensor_dtype {dtype.name} is not one a shard stores ({', '.join(SENSOR_DTYPES)})")
    return n_motor, shape, dtype


def check_block(tr: Transitions, declares: tuple[int, tuple[int, ...], np.dtype], where: str) -> None:
    """A block of drawn transitions is what the world declared: exact shapes, dtypes, motors in
    [-1, 1], finite values everywhere."""
    n_motor, shape, dtype = declares
    n = len(tr.m_t)
    expected = {"m_t": (n, n_motor), "m_t1": (n, n_motor), "s_t": (n, *shape), "s_t1": (n, *shape)}
    expected |= {name: (n, 2) for name in ("p_t", "p_t1", "shift_t", "shift_t1")}
    for name, want in expected.items():
        column = np.asarray(getattr(tr, name))
        if column.shape != want:
            raise SmspaceError(f"{where}: {name} has shape {column.shape}; the world declares {want}")
        _finite(column, name, where)
    for name in ("s_t", "s_t1"):
        if np.asarray(getattr(tr, name)).dtype != dtype:
            got = np.asarray(getattr(tr, name)).dtype
            raise SmspaceError(f"{where}: {name} is {got}; the world declares sensor_dtype {dtype.name}")
    for name in ("m_t", "m_t1"):
        _motors(np.asarray(getattr(tr, name)), name, where)


def check_regular(m: Any, p: Any, n_motor: int, where: str) -> None:
    """The regular sampling: (K, N_m) motor states in [-1, 1] and their (K, 2) positions, finite."""
    m, p = np.asarray(m), np.asarray(p)
    if m.ndim != 2 or m.shape[1] != n_motor or not 1 <= len(m) <= MAX_REGULAR:
        raise SmspaceError(f"{where}: regular_sampling() motors have shape {m.shape}; expected (K, {n_motor})")
    if p.shape != (len(m), 2):
        raise SmspaceError(f"{where}: regular_sampling() positions have shape {p.shape}; expected ({len(m)}, 2)")
    _finite(m, "regular motors", where)
    _finite(p, "regular positions", where)
    _motors(m, "regular motors", where)


def check_world(setup: Setup, world: World, seed: int) -> None:
    """A probe batch of every mode and the regular sampling, drawn from the probe's own seed stream
    (the dataset's draws are untouched), checked before anything is written."""
    from smspace.datagen.setups import setup_label, setup_plugin

    where = f"{setup_label(setup.name)}, world {seed}"
    plugin = setup_plugin(setup.name)
    declares = declared(setup, world, where)
    for mode in MODES:
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PROBE_STREAM, MODES.index(mode))))
        with plugins.guarded(plugin, f"drawing a probe batch of world {seed} ({mode})"):
            tr = draw_transitions(world, mode, rng, PROBE)
        check_block(tr, declares, f"{where}, probe batch ({mode})")
    with plugins.guarded(plugin, f"in regular_sampling() of world {seed}"):
        m, p = world.regular_sampling()
    check_regular(m, p, declares[0], where)


def _finite(column: np.ndarray, name: str, where: str) -> None:
    if column.dtype.kind not in "fiu":
        raise SmspaceError(f"{where}: {name} holds {column.dtype} values, not numbers")
    if column.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(column)))
        if bad:
            raise SmspaceError(f"{where}: {name} holds {bad} non-finite value(s) (NaN or inf); nothing was committed")


def _motors(m: np.ndarray, name: str, where: str) -> None:
    if m.size and (m.min() < -1 or m.max() > 1):
        raise SmspaceError(f"{where}: {name} lie in [{m.min():g}, {m.max():g}]; motor states must lie in [-1, 1]")
