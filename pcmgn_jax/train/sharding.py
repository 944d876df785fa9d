"""Data parallelism: the union axis of every training batch split over a 1-D device mesh ('data').

    dp = data_parallel(cfg.devices, cfg.batch_graphs)    # None: one device, arrays left where jax puts them
    rows = dp.local_rows(K, S)                           # the unions (shards) this process feeds
    batch = dp.put_batch(gather_unions(..., local_shards=rows), S)  # (K, S, ...), S split over 'data'
    state = dp.replicate(state)                          # params, optimiser state, statistics

A step's batch is S = D padded disjoint unions of B/D graphs each (:func:`pcmgn_jax.train.sampling.
gather_unions`). How: the host batch (K, S, ...) gets ``NamedSharding(mesh, P(None, 'data'))`` and
everything else a replicated ``NamedSharding(mesh, P())``; the one jitted ``train_chunk`` then compiles
for these input shardings (computation follows the data) and the SPMD partitioner runs each device's
union of the vmapped loss locally and inserts the all-reduce of the batch mean (loss, gradients). The program is
the single-device one, so the losses equal it to float tolerance (reduction order only), and there is
no second copy of the loss or of its batch reductions (a ``shard_map`` would need an explicit
``pmean``/``pmax`` for the loss, gradients and the contact-overflow flags).

Mesh axes are ``AxisType.Auto`` (``jax.make_mesh`` defaults to Explicit): the model is written for the
global view without sharding annotations, and Auto lets the partitioner propagate the batch sharding
through it.

Several hosts: call :func:`jax.distributed.initialize` before anything else touches jax; the mesh then
spans every process's devices, each process gathers only the columns :meth:`DataParallel.local_rows`
names and :meth:`DataParallel.put_batch` assembles the global array from the local pieces
(``jax.make_array_from_process_local_data``). Only exercised on forced host devices of one process.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np
from jax.sharding import AxisType, NamedSharding, PartitionSpec

from pcmgn_jax.config import check_batch_split

AXIS = "data"


class DataParallel(NamedTuple):
    mesh: jax.sharding.Mesh          # 1-D, axis 'data', D devices
    batch: NamedSharding             # (K, B, ...) host batches: B split over 'data'
    replicated: NamedSharding        # everything else: one full copy per device

    @property
    def n_devices(self) -> int:
        return int(self.mesh.devices.size)

    def replicate(self, tree):
        """``tree`` with every array leaf replicated on the mesh (static fields untouched)."""
        return jax.device_put(tree, self.replicated)

    def local_rows(self, n_steps: int, columns: int) -> np.ndarray:
        """Global batch columns (axis 1: the unions, one per device) this process's devices hold, in the
        order :meth:`put_batch` expects them (all of them on one host)."""
        idx = self.batch.addressable_devices_indices_map((n_steps, columns))
        spans = sorted({(s[1].start or 0, columns if s[1].stop is None else s[1].stop)
                        for s in idx.values()})
        return np.concatenate([np.arange(a, b) for a, b in spans])

    def put_batch(self, local, columns: int):
        """Global (K, S, ...) arrays (every leaf of the pytree ``local``) from this process's columns
        (K, S_local, ...)."""
        return jax.tree.map(lambda v: jax.make_array_from_process_local_data(
            self.batch, v, (v.shape[0], columns) + v.shape[2:]), local)


def resolve_devices(devices: int) -> int:
    """The device count of ``devices`` (0 = every device jax sees); ``ValueError`` if too many."""
    available = jax.device_count()
    n = devices or available
    if n > available:
        raise ValueError(f"config: devices={devices} but jax sees {available} device(s) ({jax.devices()}); "
                         "on a CPU, set XLA_FLAGS=--xla_force_host_platform_device_count=N before jax is "
                         "imported; on several hosts, call jax.distributed.initialize first")
    return n


def data_parallel(devices: int, batch_graphs: int) -> DataParallel | None:
    """The 1-D 'data' mesh over ``devices`` devices (0 = all), or None when that is one device.

    Raises ``ValueError`` naming the fields when ``batch_graphs`` is not divisible by the count.
    """
    n = resolve_devices(devices)
    check_batch_split(batch_graphs, n)
    if n == 1:
        return None
    mesh = jax.make_mesh((n,), (AXIS,), axis_types=(AxisType.Auto,), devices=jax.devices()[:n])
    return DataParallel(mesh, NamedSharding(mesh, PartitionSpec(None, AXIS)), NamedSharding(mesh, PartitionSpec()))
