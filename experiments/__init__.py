from pcmgn_jax.compile_cache import enable_compile_cache
from pcmgn_jax.heap import keep_freed_memory

keep_freed_memory()  # before any JAX computation (pcmgn_jax/heap.py)
enable_compile_cache()  # compiled programs persist across runs (pcmgn_jax/compile_cache.py; PCMGN_JAX_CACHE=0: off)
