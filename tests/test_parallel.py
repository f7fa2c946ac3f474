"""Sharding the condition axis over devices (`mrjax.parallel`,
`mrjax.fit(chunks=mrjax.Chunks(devices=...))`).

The multi-device check runs in a subprocess with `--xla_force_host_platform_device_count=2`:
the pytest process has already started JAX with one CPU device.
"""

import json
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest
from helpers import POLISH_RMS_RTOL, SWARM_RTOL, assert_same_polish, assert_same_swarms

import mrjax
from mrjax.data import paper_grid
from mrjax.parallel import pad_conditions, resolve_devices, shard_batch, unpad


@pytest.fixture(scope="module")
def small():
    return paper_grid(currents=(0.0, 1.0, 2.0), motions=((1.0, 0.008),), cycles=1,
                      sample_rate=500.0)


def test_resolve_devices():
    assert resolve_devices(None) == [jax.devices()[0]]
    assert resolve_devices("all") == list(jax.devices())
    assert resolve_devices(1) == [jax.devices()[0]]
    assert resolve_devices(jax.devices()) == list(jax.devices())
    for bad in ("some", 0, len(jax.devices()) + 1, [], [1, 2], 3.5):
        with pytest.raises(mrjax.InputError):
            resolve_devices(bad)
    with pytest.raises(mrjax.InputError):
        resolve_devices([jax.devices()[0], jax.devices()[0]])


def test_pad_and_unpad(small):
    b, m, n = pad_conditions(small, None, 2)
    assert n == 3 and b.n_conditions == 4 and len(b.labels) == len(set(b.labels)) == 4
    np.testing.assert_array_equal(np.asarray(b.x)[3], np.asarray(small.x)[2])
    np.testing.assert_array_equal(np.asarray(m)[:3], np.asarray(small.mask))
    same, _, n = pad_conditions(small, None, 3)
    assert same is small and n == 3
    res = mrjax.fit("kwok", b, swarm=mrjax.Swarm(generations=3), polish=None)
    cut = unpad(res, 3)
    assert cut.n_conditions == 3 and cut.theta.shape == (3, 6) and cut.history.shape[0] == 3
    assert cut.labels == small.labels and cut.timings == res.timings


def test_single_device_fit_unchanged(small):
    """devices=1 places the batch on one device and gives the same numbers as no devices."""
    b, m = shard_batch(small, None, 1)
    assert b.n_conditions == small.n_conditions and m.shape == small.mask.shape
    kw = dict(swarm=mrjax.Swarm(generations=5),
              polish=mrjax.Polish(max_steps=20, uncertainty=False), key=1)
    a = mrjax.fit("kwok", small, **kw)
    c = mrjax.fit("kwok", small, chunks=mrjax.Chunks(devices=1), **kw)
    np.testing.assert_array_equal(a.theta, c.theta)
    np.testing.assert_array_equal(a.rms, c.rms)


_SCRIPT = textwrap.dedent("""
    import json, sys
    import jax, numpy as np
    import mrjax
    from mrjax.data import paper_grid
    assert len(jax.devices()) == 2, jax.devices()
    # 3 conditions: padded to 4 on 2 devices
    batch = paper_grid(currents=(0.0, 1.0, 2.0), motions=((1.0, 0.008),), cycles=1,
                       sample_rate=500.0)
    out = {}
    for name, kw in (("pso+lm", dict(polish=mrjax.Polish(max_steps=20, uncertainty=False))),
                     ("pso-full", dict(swarm=mrjax.Swarm(mode="full", generations=8),
                                       polish=None))):
        one = mrjax.fit("kwok", batch, key=3, **kw)
        two = mrjax.fit("kwok", batch, key=3, chunks=mrjax.Chunks(devices="all"), **kw)
        r = {"C": [one.n_conditions, two.n_conditions], "labels_equal": one.labels == two.labels}
        for f in ("theta", "rms", "nrmse", "generations", "stopped_by_criterion", "n_samples",
                  "history", "pso_rms"):
            r[f] = [np.asarray(getattr(one, f)).tolist(), np.asarray(getattr(two, f)).tolist()]
        out[name] = r
    # the sharded batch really lives on both devices
    from mrjax.parallel import shard_batch
    b, m = shard_batch(batch, None, "all")
    out["n_devices_of_x"] = len(b.x.sharding.device_set)
    out["padded_C"] = b.n_conditions
    print(json.dumps(out))
""")


def test_sharded_fit_identical_to_single_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, env=env,
                       timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["n_devices_of_x"] == 2 and out["padded_C"] == 4
    for name in ("pso+lm", "pso-full"):
        r = out[name]
        assert r["C"] == [3, 3] and r["labels_equal"], r
        # The same fit to rounding: with the condition axis split, XLA reduces the
        # per-condition sums with kernels tiled for the local shape (last bits), so a stop
        # within rounding of its threshold may move (see `helpers.assert_same_swarms`; the
        # polish's step counts are not compared). Padding or a shard fitted on another
        # condition's data moves them by percents.
        (ga, gb), (ha, hb) = r["generations"], r["history"]
        assert_same_swarms(ga, gb, np.array(ha, float), np.array(hb, float))
        assert r["n_samples"][0] == r["n_samples"][1]
        same = np.equal(ga, gb)
        (sa, sb), (pa, pb) = r["stopped_by_criterion"], r["pso_rms"]
        assert np.array_equal(np.array(sa)[same], np.array(sb)[same])
        np.testing.assert_allclose(np.array(pa, float)[same], np.array(pb, float)[same],
                                   rtol=SWARM_RTOL)
        if name == "pso-full":  # a fixed generation count, no polish: the swarm's result
            np.testing.assert_allclose(*r["theta"], rtol=SWARM_RTOL)
            np.testing.assert_allclose(*r["rms"], rtol=SWARM_RTOL)
        assert_same_polish(*r["rms"], *r["theta"])
        np.testing.assert_allclose(*r["nrmse"], rtol=POLISH_RMS_RTOL)
