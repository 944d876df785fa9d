"""Benchmarks (issue 6): ``python -m benchmarks.NAME``; each writes JSON + a Markdown table.

- ``mgn_vs_torch``     JAX MeshGraphNet against a plain-PyTorch reference on the same graph
- ``rollout_throughput``  100-frame rollouts, batched over designs (designs/s)
- ``solver_speed``     the built-in explicit solver: substeps/s, wall time per trajectory
- ``speed_vs_error``   trained surrogates against solver presets: wall time vs error (Pareto plot)
- ``train_step``       the training loop's own step on a dataset: time per step, host work, FLOP rate, op profile

Benchmarks are not tests: tests only run them at tiny sizes. Ratios measured in the same run carry
the claims; absolute times depend on the machine recorded in each JSON's ``machine`` block.
"""
from pcmgn_jax.compile_cache import enable_compile_cache
from pcmgn_jax.heap import keep_freed_memory

keep_freed_memory()  # before any JAX computation: XLA's per-call scratch buffer stays mapped (pcmgn_jax/heap.py)
enable_compile_cache()  # compiled programs persist across runs (pcmgn_jax/compile_cache.py; PCMGN_JAX_CACHE=0: off)
