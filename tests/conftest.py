import jax

# Tests compare against float64 oracles; the library itself never touches this flag.
jax.config.update("jax_enable_x64", True)
