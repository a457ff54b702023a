"""The studio's light in the captured colours.

A multi-view studio textures each frame from its photographs, so the colours it delivers are
the albedo as lit in that frame, not the albedo: the lights stay where they are while the
performer turns under them, each camera exposes and white-balances every frame a little
differently, and the images are noisy. A body part facing the key light in one frame and turned
away from it in another comes out up to a third brighter, and two frames' colours never agree
exactly even where the correspondence is perfect. This is what colour cues on real captures have
to live with (engine.align.appearance), so the studio presets deliver it too.

The model: ambient light and two directional lights fixed in the studio (a key from the front,
above and to the left; a dimmer fill from behind on the right), Lambert shading on the true
surface's normals (the photographs see the true surface), normalised so that the mean over all
directions leaves the albedo unchanged; a per-frame gain and white balance; per-vertex noise.
Ambient occlusion and specular highlights are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StudioLight:
    """Light and exposure of the studio (directions in metres, Y up, +Z the studio's front).

    ambient : light from everywhere (the studio's diffuse walls)
    key, fill : (direction towards the light, strength) of the two directional lights
    exposure : standard deviation of each frame's overall gain
    white_balance : standard deviation of each frame's per-channel gain
    noise : standard deviation of per-vertex colour noise (sensor and compression)
    """

    ambient: float = 0.7
    key: tuple = ((0.45, 0.8, 0.4), 0.3)
    fill: tuple = ((-0.6, 0.3, -0.5), 0.12)
    exposure: float = 0.03
    white_balance: float = 0.015
    noise: float = 0.01

    def shading(self, normals):
        """Brightness factor of surfaces with these unit normals (mean 1 over all directions)."""
        total = np.full(len(normals), float(self.ambient))
        mean = float(self.ambient)
        for direction, strength in (self.key, self.fill):
            d = np.asarray(direction, dtype=np.float64)
            total += strength * np.clip(normals @ (d / np.linalg.norm(d)), 0.0, None)
            mean += 0.25 * strength   # the mean of max(n . d, 0) over the sphere
        return total / mean


def lit_colours(albedo, normals, rng, light):
    """Colours as the studio captures them in one frame.

    Parameters
    ----------
    albedo : (k, 3) float array in [0, 1]
    normals : (k, 3) float array   unit normals of the true surface where the colours are seen
    rng : numpy Generator          the frame's own randomness
    light : StudioLight

    Returns
    -------
    colours : (k, 3) float array in [0, 1]
    """
    gain = (1.0 + rng.normal(0.0, light.exposure)) * (1.0 + rng.normal(0.0, light.white_balance, 3))
    shaded = np.asarray(albedo, dtype=np.float64) * light.shading(np.asarray(normals, dtype=np.float64))[:, None]
    return np.clip(shaded * gain + rng.normal(0.0, light.noise, shaded.shape), 0.0, 1.0)


__all__ = ["StudioLight", "lit_colours"]
