"""Perlin gradient noise in JAX (no ``noise`` package): one random gradient field per PRNG key.

Lattice points sit at integer multiples of ``1 / frequency`` from the world origin, so the noise is
exactly 0 at the origin (where the robot spawns) for every octave.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def _fade(t: jax.Array) -> jax.Array:
    """Perlin's quintic smoothstep 6t^5 - 15t^4 + 10t^3."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def lattice_size(frequency: float, extent: float) -> int:
    """Lattice points per axis needed to cover [-extent, extent] at ``frequency`` (static)."""
    return 2 * int(math.ceil(frequency * extent)) + 2


def gradient_noise(key: jax.Array, x: jax.Array, y: jax.Array, frequency: float, extent: float) -> jax.Array:
    """One octave of 2-D Perlin noise at world points (x, y) inside [-extent, extent]^2.

    Unit gradients with uniformly random directions on the lattice; the result lies within
    about +-0.7 and is 0 on every lattice point.
    """
    n = lattice_size(frequency, extent)
    offset = n // 2 - 1  # lattice index of the point at the origin
    angles = jax.random.uniform(key, (n, n), minval=0.0, maxval=2.0 * jnp.pi)
    grads = jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=-1)
    px, py = x * frequency, y * frequency
    ix = jnp.clip(jnp.floor(px).astype(jnp.int32) + offset, 0, n - 2)
    iy = jnp.clip(jnp.floor(py).astype(jnp.int32) + offset, 0, n - 2)
    fx, fy = px - (ix - offset), py - (iy - offset)

    def corner(dx: int, dy: int) -> jax.Array:
        """Gradient of lattice corner (dx, dy) dotted with the offset to the point."""
        g = grads[iy + dy, ix + dx]
        return g[..., 0] * (fx - dx) + g[..., 1] * (fy - dy)

    sx, sy = _fade(fx), _fade(fy)
    bottom = corner(0, 0) + sx * (corner(1, 0) - corner(0, 0))
    top = corner(0, 1) + sx * (corner(1, 1) - corner(0, 1))
    return bottom + sy * (top - bottom)


def fractal_noise(
    key: jax.Array,
    x: jax.Array,
    y: jax.Array,
    frequency: float,
    octaves: int,
    persistence: float,
    lacunarity: float,
    extent: float,
) -> jax.Array:
    """Sum of ``octaves`` Perlin octaves (frequency x lacunarity^k, weight persistence^k), divided
    by the sum of the weights (the normalisation of the ``noise`` package's ``pnoise2``)."""
    keys = jax.random.split(key, octaves)
    total = jnp.zeros(jnp.broadcast_shapes(jnp.shape(x), jnp.shape(y)), jnp.float32)
    weight_sum = 0.0
    for k in range(octaves):  # static octave count: unrolled at trace time
        weight = persistence**k
        total = total + weight * gradient_noise(keys[k], x, y, frequency * lacunarity**k, extent)
        weight_sum += weight
    return total / weight_sum
