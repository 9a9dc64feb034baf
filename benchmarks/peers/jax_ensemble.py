"""What a researcher who wanted speed would write by hand in JAX: the same network (Glorot-uniform
kernels, zero biases, SELU, siamese encoder, predictor on (h_t, h_t1, s_t), squared error summed
over sensor components and averaged over the batch), R runs at once with jax.vmap, one jitted
update with optax's Adam on the same linear schedule (1e-3 -> 1e-5 over 80 % of the steps, then
constant), and each run's batch of 100 drawn with replacement in numpy at every step.

Runs in the peers' environment (requirements.txt), started by run.py on one pinned core.
Prints one JSON line: the steady ms per run-step (after `--warmup` steps) and the warm-up's seconds.
Usage: python jax_ensemble.py DATA.npz [--runs 30] [--steps 3000] [--warmup 1000] [--nh 3]
"""

from __future__ import annotations

import itertools
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")

import jax
import jax.numpy as jnp
import numpy as np
import optax
from contender import ENCODER, PREDICTOR, arguments, columns, report


def init_mlp(key, sizes):
    layers = []
    for fan_in, fan_out in itertools.pairwise(sizes):
        key, sub = jax.random.split(key)
        limit = np.sqrt(6.0 / (fan_in + fan_out))
        layers.append((jax.random.uniform(sub, (fan_in, fan_out), jnp.float32, -limit, limit), jnp.zeros(fan_out)))
    return layers


def apply_mlp(layers, x):
    for i, (w, b) in enumerate(layers):
        x = x @ w + b
        if i < len(layers) - 1:
            x = jax.nn.selu(x)
    return x


def init_net(key, n_m: int, n_s: int, n_h: int):
    k_enc, k_pred = jax.random.split(key)
    return {
        "encoder": init_mlp(k_enc, [n_m, *ENCODER, n_h]),
        "predictor": init_mlp(k_pred, [2 * n_h + n_s, *PREDICTOR, n_s]),
    }


def loss_fn(params, m_t, s_t, m_t1, s_t1):
    h = apply_mlp(params["encoder"], jnp.concatenate([m_t, m_t1]))
    h_t, h_t1 = h[: len(m_t)], h[len(m_t) :]
    pred = apply_mlp(params["predictor"], jnp.concatenate([h_t, h_t1, s_t], axis=1))
    return jnp.mean(jnp.sum((pred - s_t1) ** 2, axis=1))


def main() -> None:
    args = arguments(ensemble=True)
    data = columns(args.data)
    n_m, n_s = data[0].shape[1], data[1].shape[1]

    keys = jax.random.split(jax.random.PRNGKey(0), args.runs)
    params = jax.vmap(lambda k: init_net(k, n_m, n_s, args.nh))(keys)
    schedule = optax.linear_schedule(1e-3, 1e-5, round(0.8 * args.steps))
    optimizer = optax.adam(schedule)
    opt_state = jax.vmap(optimizer.init)(params)

    def one_run(p, state, batch):
        loss, grads = jax.value_and_grad(loss_fn)(p, *batch)
        updates, state = optimizer.update(grads, state, p)
        return optax.apply_updates(p, updates), state, loss

    update = jax.jit(jax.vmap(one_run))
    rng = np.random.default_rng(0)
    started = time.perf_counter()
    for i in range(args.steps):
        if i == args.warmup:
            jax.block_until_ready(params)
            steady_from = time.perf_counter()
        idx = rng.choice(len(data[0]), (args.runs, args.batch), replace=True)
        batch = tuple(jnp.asarray(c[idx]) for c in data)
        params, opt_state, _ = update(params, opt_state, batch)
    jax.block_until_ready(params)
    ended = time.perf_counter()
    name = f"JAX vmap + jit + optax Adam, {args.runs} run(s) at once"
    report(name, args.runs, ended - steady_from, args.steps - args.warmup, steady_from - started, jax=jax.__version__)


if __name__ == "__main__":
    main()
