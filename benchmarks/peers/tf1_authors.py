"""The authors' pipeline, as their code trains (docs/MODEL.md §3 describes the network): a TF1 graph
through tf.compat.v1 — float32 placeholders, dense layers with Glorot-uniform kernels and zero
biases, SELU, the encoder built twice in one variable scope (siamese: shared weights), the
predictor on (h_t, h_t1, s_t), squared error summed over sensor components and averaged over the
batch, AdamOptimizer on polynomial_decay(1e-3 -> 1e-5 over 80 % of the steps, power 1) — fed one
numpy batch of 100 transitions drawn with replacement from the whole dataset at every step. One
run at a time, as they trained. (Their dense layers are tf.layers.dense, gone with Keras 3: the
same MatMul + BiasAdd are written out here.)

Runs in the peers' environment (requirements.txt), started by run.py on one pinned core.
Prints one JSON line: the steady ms per step (after `--warmup` steps) and the warm-up's seconds.
Usage: python tf1_authors.py DATA.npz [--steps 3000] [--warmup 1000] [--nh 3]
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

import numpy as np
import tensorflow as tf
from contender import ENCODER, PREDICTOR, arguments, columns, report

tf1 = tf.compat.v1


def dense(x, units: int, name: str, activation=None):
    with tf1.variable_scope(name):
        w = tf1.get_variable("kernel", [x.shape[-1], units], initializer=tf1.glorot_uniform_initializer())
        b = tf1.get_variable("bias", [units], initializer=tf1.zeros_initializer())
        y = tf.nn.bias_add(tf.matmul(x, w), b)
        return activation(y) if activation is not None else y


def mlp(x, sizes, out: int):
    for i, units in enumerate(sizes):
        x = dense(x, units, f"layer{i}", tf.nn.selu)
    return dense(x, out, "layerend")


def main() -> None:
    args = arguments(ensemble=False)
    m_t, s_t, m_t1, s_t1 = columns(args.data)
    n_m, n_s = m_t.shape[1], s_t.shape[1]

    tf1.disable_eager_execution()
    graph = tf1.Graph()
    with graph.as_default():
        tf1.set_random_seed(0)
        motor_t = tf1.placeholder(tf.float32, [None, n_m])
        motor_tp = tf1.placeholder(tf.float32, [None, n_m])
        sensor_t = tf1.placeholder(tf.float32, [None, n_s])
        sensor_tp = tf1.placeholder(tf.float32, [None, n_s])
        with tf1.variable_scope("motor_encoding", reuse=tf1.AUTO_REUSE):
            h_t = mlp(motor_t, ENCODER, args.nh)
        with tf1.variable_scope("motor_encoding", reuse=tf1.AUTO_REUSE):
            h_tp = mlp(motor_tp, ENCODER, args.nh)
        with tf1.variable_scope("sensory_prediction"):
            pred = mlp(tf.concat([h_t, h_tp, sensor_t], axis=1), PREDICTOR, n_s)
        loss = tf.reduce_mean(tf.reduce_sum(tf.square(pred - sensor_tp), axis=1))
        step = tf1.train.get_or_create_global_step()
        lr = tf1.train.polynomial_decay(1e-3, step, round(0.8 * args.steps), 1e-5, power=1.0)
        train = tf1.train.AdamOptimizer(lr).minimize(loss, global_step=step)
        init = tf1.global_variables_initializer()
    config = tf1.ConfigProto(intra_op_parallelism_threads=1, inter_op_parallelism_threads=1)
    rng = np.random.default_rng(0)
    with tf1.Session(graph=graph, config=config) as sess:
        sess.run(init)
        started = time.perf_counter()
        for i in range(args.steps):
            if i == args.warmup:
                steady_from = time.perf_counter()
            idx = rng.choice(len(m_t), args.batch, replace=True)
            feed = {motor_t: m_t[idx], sensor_t: s_t[idx], motor_tp: m_t1[idx], sensor_tp: s_t1[idx]}
            sess.run(train, feed_dict=feed)
        ended = time.perf_counter()
    name = "authors' TF1 graph (tf.compat.v1), one run"
    report(name, 1, ended - steady_from, args.steps - args.warmup, steady_from - started, tensorflow=tf.__version__)


if __name__ == "__main__":
    main()
