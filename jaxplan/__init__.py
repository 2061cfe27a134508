"""jaxplan: JAX-accelerated, batched decentralized multi-robot trajectory optimization.

Importing the package enables float64 in JAX (DESIGN.md: float64 everywhere).
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
