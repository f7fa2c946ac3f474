"""The README's multi-host recipe: one swarm over the devices of several processes (hosts).

Start the same command in every process, with its own `--process-id`:

```bash
python examples/multihost.py --coordinator host0:1234 --num-processes 2 --process-id 0 &
python examples/multihost.py --coordinator host0:1234 --num-processes 2 --process-id 1
```

Each process then writes the gathered result (every condition's parameters and RMS, the same
in every process) as JSON to `--out` (default stdout). `tests/test_multihost.py` runs it in two
local processes on CPU and checks it against a single-process `mrjax.fit`; the code between
the `recipe` markers is the README's recipe, verbatim (the test checks that too).
"""

from __future__ import annotations

import argparse
import json
import sys


def main(argv: list[str] | None = None) -> int:
    """Run the recipe with the arguments of one process; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coordinator", required=True, metavar="HOST:PORT",
                        help="address of process 0's coordinator service")
    parser.add_argument("--num-processes", type=int, required=True, metavar="N")
    parser.add_argument("--process-id", type=int, required=True, metavar="RANK")
    parser.add_argument("--out", metavar="FILE", help="write the result here (default stdout)")
    a = parser.parse_args(argv)
    ADDRESS, N, RANK = a.coordinator, a.num_processes, a.process_id  # noqa: N806

    # --- recipe ---
    import jax

    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU hosts talk over TCP
    jax.distributed.initialize(coordinator_address=ADDRESS, num_processes=N, process_id=RANK)

    import numpy as np
    from jax.experimental.multihost_utils import process_allgather

    import mrjax
    from mrjax.parallel import shard_batch

    # the same data in every process (e.g. mrjax.data.load_batch("tests/"))
    batch = mrjax.data.paper_grid(currents=(0.0, 0.5, 1.0, 2.0), motions=((1.0, 0.008),),
                                  cycles=1, sample_rate=500.0)
    C = batch.n_conditions
    model = mrjax.models.get("kwok")
    b, mask = shard_batch(batch, None, "all")  # each process fills its own devices' shards
    sw = mrjax.fitting.fit_swarm(model, b, key=jax.random.key(0), mask=mask)
    theta = np.asarray(process_allgather(sw.theta, tiled=True))[:C]  # (C, P) in every process
    rms = np.asarray(process_allgather(sw.rms, tiled=True))[:C]  # (C,) [N]
    # --- end of recipe ---

    doc = {"process_id": RANK, "n_devices": len(jax.devices()),
           "n_local_devices": len(jax.local_devices()),
           "n_devices_of_x": len(b.x.sharding.device_set),
           "theta": theta.tolist(), "rms": rms.tolist(),
           "generations": np.asarray(process_allgather(sw.result.generations,
                                                       tiled=True))[:C].tolist(),
           "history": np.asarray(process_allgather(sw.result.history, tiled=True))[:C].tolist()}
    text = json.dumps(doc)  # floats by repr: exact
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text)
    else:
        print(text)
    jax.distributed.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
