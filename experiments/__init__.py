from pcmgn_jax.heap import keep_freed_memory

keep_freed_memory()  # before any JAX computation (pcmgn_jax/heap.py)
