"""Parameters of one terrain: the fields of a terrain catalogue's class (design §6.1, §10).

Its own module so that the catalogue reader (:mod:`terrainml.lookup.catalogue`) and the
terramechanics (:mod:`terrainml.lookup.terramechanics`, whose nominal table is read from the
reference catalogue) share it without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

__all__ = ["TerrainParams"]


@dataclass(frozen=True)
class TerrainParams:
    """Parameters of one terrain (a class's nominal values or one run's realisation).

    Units: pressures Pa, ``k_c`` N/m^(n+1), ``k_phi`` N/m^(n+2), lengths m, angles rad.
    """

    class_id: int
    name: str
    model: str                      # "burckhardt" | "soil"
    # Burckhardt tyre-road curve
    c1: float = 0.0
    c2: float = 0.0
    c3: float = 0.0
    # rolling resistance coefficient (burckhardt and layer soils)
    crr: float = 0.0
    # Mohr-Coulomb and shear
    cohesion_pa: float = 0.0
    friction_angle_rad: float = 0.0
    shear_modulus_m: float = 0.02   # K (JH) or K_omega (hump: displacement of the shear peak)
    residual_ratio: float = 1.0     # K_r; 1 = Janosi-Hanamoto, < 1 = Wong hump-type
    # Bekker pressure-sinkage (k_phi == 0: not a Bekker soil, use layer_depth_m)
    n_exp: float = 1.0
    k_c: float = 0.0
    k_phi: float = 0.0
    layer_depth_m: float = 0.0
    slip_sinkage: float = 1.0       # gain a of z(s) = z0 (1 + a s) / (1 - 0.5 a s)
    free_slip: float = 0.0          # s_f: slip taken up by the compressible top layer before shear
    # lateral force: F_y = -lateral_mu W tanh(alpha / lateral_alpha0_rad)
    lateral_mu: float = 0.8
    lateral_alpha0_rad: float = 0.12
    # surface roughness for the simulator (vertical profile): rms height and the band of
    # wavelengths it lives in. The band is the class's vibration signature: loose stones
    # (gravel) shake at short wavelengths (5-17 Hz at 1 m/s), sod and sand ripples undulate
    # slowly (below 4 Hz). Assumption, chosen so imu_az spectra differ the way they do on real
    # robots; not a calibration target.
    roughness_rms_m: float = 0.001
    roughness_wavelength_min_m: float = 0.12
    roughness_wavelength_max_m: float = 1.5
    sources: str = ""

    @property
    def is_bekker(self) -> bool:
        return self.model == "soil" and self.k_phi > 0.0

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}
