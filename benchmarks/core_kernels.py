"""Time the core kernels batched over 10 .. 10,000 particles on this CPU.

Usage: python benchmarks/core_kernels.py [--particles 10 100 1000 10000] [--quick]

Each kernel is jitted once per particle count and timed after compilation (median of
repeats). Writes benchmarks/results/core_kernels.json and prints a table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, time_call, write_json  # noqa: E402

from jaxslam.core import (  # noqa: E402
    UTParams,
    chol_update,
    selective_resample,
    sigma_points,
    sqrt_ut_moments,
    systematic,
    residual,
    tria,
    unscented_transform,
    ut_weights,
)
from jaxslam.core.se2 import pose_mean, pose_residual  # noqa: E402


def odometry(p):
    """[pose; 2 noise] -> pose: the kind of map an odometry UT pushes sigma points through."""
    v, w = 0.5 + p[3], 0.1 + p[4]
    return jnp.stack([p[0] + v * jnp.cos(p[2] + w), p[1] + v * jnp.sin(p[2] + w), p[2] + w])


def kernels(n_particles: int, key):
    k1, k2, k3 = jax.random.split(key, 3)
    n = 5
    means = jax.random.normal(k1, (n_particles, n))
    a = jax.random.normal(k2, (n_particles, n, n)) * 0.1
    chols = jnp.linalg.cholesky(a @ jnp.swapaxes(a, -1, -2) + jnp.eye(n))
    vecs = jax.random.normal(k3, (n_particles, n)) * 0.1
    log_w = jax.random.normal(k3, (n_particles,))
    params = UTParams(jnp.asarray(0.5), jnp.asarray(2.0), jnp.asarray(0.0))
    wm, wc, _ = ut_weights(n, params)
    stacked = jax.random.normal(k1, (n_particles, 3, 10))

    sigma = jax.jit(lambda m, c: sigma_points(m, c, params))
    ut = jax.jit(lambda m, c: unscented_transform(odometry, m, c, params,
                                                  mean_fn=pose_mean, residual_fn=pose_residual).cov)
    pts = sigma_points(means, chols, params)
    prop = jax.vmap(jax.vmap(odometry))(pts)
    srut = jax.jit(lambda p: sqrt_ut_moments(p, wm, wc, pose_mean, pose_residual)[1])
    update = jax.jit(lambda c, v: chol_update(c, v, -1.0))
    qr = jax.jit(tria)
    sys_rs = jax.jit(systematic)
    res_rs = jax.jit(residual)
    sel = jax.jit(lambda k, lw: selective_resample(k, lw, 0.5)[0])
    return {
        "sigma_points (n=5)": lambda: sigma(means, chols),
        "unscented_transform odometry (n=5)": lambda: ut(means, chols),
        "sqrt_ut_moments (n=5 -> 3)": lambda: srut(prop),
        "chol_downdate (n=5)": lambda: update(chols, vecs),
        "tria 3x10": lambda: qr(stacked),
        "systematic resample": lambda: sys_rs(key, log_w),
        "residual resample": lambda: res_rs(key, log_w),
        "selective_resample": lambda: sel(key, log_w),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[10, 100, 1000, 10000])
    parser.add_argument("--quick", action="store_true", help="fewer repeats (smoke test)")
    args = parser.parse_args(argv)
    rows = []
    key = jax.random.PRNGKey(0)
    for n_particles in args.particles:
        for name, fn in kernels(n_particles, key).items():
            seconds = time_call(fn, repeats=3 if args.quick else 7, min_time=0.05 if args.quick else 0.5)
            rows.append({
                "kernel": name,
                "particles": n_particles,
                "us_per_call": seconds * 1e6,
                "ns_per_particle": seconds * 1e9 / n_particles,
            })
    print_table(rows, ["kernel", "particles", "us_per_call", "ns_per_particle"])
    path = write_json("core_kernels", {"dtype": "float32", "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
