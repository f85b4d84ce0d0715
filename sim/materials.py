"""NIR material table of the lab's targets (Thesis 2024, 4.1.1, 5.4.1 Table 5-2, 6.2.1, 6.5).

Per material:

* ``remission_850``, ``remission_940``: diffuse NIR reflectance (0..1) at the
  two ToF wavelengths. ``remission`` interpolates linearly in wavelength,
  rho(l) = rho_850 + (rho_940 - rho_850) (l - 850) / 90, and continues the same
  line from 800 to 1000 nm; outside that range it raises ValueError.
* ``subsurface_bias_mm``: how much farther a CW-ToF camera measures the surface
  because light scatters below it before leaving (0 for opaque surfaces),
  for the lab cameras' 60-100 MHz modulation. No ToF measurement on these
  materials is published; the values are estimates guided by
  frequency-domain diffusion theory for a slab of thickness L (index n,
  absorption mu_a, reduced scattering mu_s', extrapolated boundary):

      R(w) ~ sinh(k (L + z_b - z_0)) / sinh(k (L + 2 z_b)),
      k = sqrt(3 (mu_a + mu_s') (mu_a + i w n / c)),
      z_0 = 1 / (mu_a + mu_s'),  z_b = 2 A / (3 (mu_a + mu_s')),
      bias = -arg R(w) * c / (2 w),  w = 2 pi f_mod,

  with A the internal-reflection factor of the index mismatch. Skin
  (mu_s' = 4.6 (l / 500 nm)^-1.421 mm^-1 = 2.2 mm^-1 at 850 nm, Jacques,
  Phys. Med. Biol. 58 R37, 2013; mu_a = 0.03 mm^-1 assumed, the order of
  in-vivo NIR values; n = 1.4) gives a remission of 0.53 and a bias of 7 mm,
  nearly independent of f_mod; the total diffuse reflectance of a
  semi-infinite medium in the same theory gives 0.57 and 6 mm. PTFE
  (mu_a < 0.001 mm^-1 and scattering far above tissue's, Li et al. 2008;
  mu_s' = 10-30 mm^-1 assumed for the NIR; n = 1.35; a 10 mm plate) gives
  8-14 mm at 100 MHz and 16-19 mm at 20 MHz.
* ``lambertian_exponent`` m: the signal a camera receives back from a surface
  tilted by theta to its line of sight (illumination and camera on the same
  axis, as in ToF and active stereo) scales with ``angle_factor`` = cos(theta)^m.
  m = 1 is a Lambertian surface (irradiance ~ cos theta, radiance the same in
  every direction); m > 1 a surface that sends part of the light away
  specularly. One exponent is enough for Thesis 2024's angle study (5.4, 6.5),
  which only compares materials by how fast their signal falls with angle.

Values (``Material.source`` gives the sources per material):

    name          850 nm   940 nm   bias mm   m     basis
    ptfe          0.95     0.95     10        1     literature; bias: diffusion estimate
    molleton      0.10     0.10     0         1     Thesis 2024, 4.1.1 (Fig. B-1)
    silicone      0.50     0.48     5         1     assumption inside the skin range
    gelatine      0.52     0.49     5         1     assumption inside the skin range
    collagen      0.35     0.33     3         2     assumption (thin glossy film)
    wall          0.90     0.90     0         1     Thesis 2024, 4.1.1 (Fig. B-1)
    chart_white   0.80     0.80     0         1     assumption (paper)
    chart_black   0.0076   0.0076   0         1     chart_white / 105 (Thesis 2024, 6.2.1)
    paper_white   0.80     0.80     0         1     assumption (paper)

Ranges found. PTFE 0.92-0.99: Spectralon (sintered PTFE powder) > 0.99
from 400 to 1500 nm (Labsphere); sintered PTFE plates 0.925-0.945 for 5-10 mm
at 450 nm (NEXT Collaboration, JINST 15 P11031, 2020) and >= 0.98 for a
10 mm slab at 635 nm (Li et al., J. Biomed. Opt. 13, 054064, 2008). Human
skin roughly 0.4-0.6 at 850-940 nm, lower at 940 nm (water band) and for
darker skin: the diffusion estimate above gives 0.51-0.57; reflectance peaks
at 720-840 nm for light and near 900 nm for dark skin (Kuppenheim and Heer
1951); NIST publishes reference spectra (Cooksey et al., J. Res. NIST 122,
2017). Thesis 2024 (Fig. B-3) compares its skin-like targets with the skin
spectra of Rest (2022) without giving numbers. Subsurface bias: PTFE mm to
cm (diffusion estimate 6-20 mm; its reflectance still grows from 5 to 10 mm
thickness, so light reaches that deep); skin 5-7 mm (diffusion estimate),
and 8-15 mm reported for hands seen by an Azure Kinect (850 nm ToF) against
paper taped onto them (github.com/microsoft/Azure-Kinect-Sensor-SDK issue
1341); a translucent silicone mat reads visibly too far with the same camera
(issue 1305).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WAVELENGTH_RANGE_NM = (800.0, 1000.0)


@dataclass(frozen=True)
class Material:
    """NIR properties of one target material; see the module docstring for the meaning of each field."""

    name: str
    remission_850: float
    remission_940: float
    subsurface_bias_mm: float
    lambertian_exponent: float
    source: str

    def __post_init__(self) -> None:
        for value in (self.remission_850, self.remission_940):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{self.name}: remission {value} is not within 0..1")
        if self.subsurface_bias_mm < 0.0:
            raise ValueError(f"{self.name}: subsurface bias must not be negative")
        if self.lambertian_exponent <= 0.0:
            raise ValueError(f"{self.name}: lambertian exponent must be positive")


_PAPER = (
    "assumption: uncoated paper scatters strongly and barely absorbs at 850-940 nm; "
    "a single sheet lets part of the light through, so 0.80 (0.7-0.9)"
)
_SKIN_LIKE = (
    "assumption: no NIR data exist for this material; chosen inside the roughly 0.4-0.6 of human skin at "
    "850-940 nm (diffusion estimate 0.51-0.57, see the module docstring), ordered by Thesis 2024's "
    "repeatabilities (6.5.2: gelatine slightly better than silicone, collagen worst of the skin-like "
    "targets), with 940 nm a little lower as for skin (water band)"
)
_SKIN_BIAS = (
    "bias 5 mm: a turbid skin-like medium, diffusion estimate for skin 5-7 mm (mu_s' Jacques 2013), "
    "8-15 mm reported on hands (Azure Kinect SDK issue 1341)"
)

MATERIALS: dict[str, Material] = {
    m.name: m
    for m in (
        Material(
            "ptfe", remission_850=0.95, remission_940=0.95, subsurface_bias_mm=10.0, lambertian_exponent=1.0,
            source="0.95 between sintered PTFE plates (0.925-0.945 at 450 nm for 5-10 mm, NEXT Collaboration "
            "JINST 2020; >=0.98 for 10 mm at 635 nm, Li et al. 2008) and Spectralon (>0.99, Labsphere); "
            "highly Lambertian (Labsphere); bias 10 mm from frequency-domain diffusion theory for a 10 mm "
            "plate, mu_s' 10-30 mm^-1 assumed, mu_a < 0.001 mm^-1 (Li et al. 2008): 8-14 mm at 100 MHz",
        ),
        Material(
            "molleton", remission_850=0.10, remission_940=0.10, subsurface_bias_mm=0.0, lambertian_exponent=1.0,
            source="Thesis 2024, 4.1.1 and Fig. B-1: black molleton reflects 10 % at 850 and 940 nm; opaque cotton "
            "fabric (bias 0, assumption); Lambertian (assumption: napped, rough diffuse surface)",
        ),
        Material(
            "silicone", remission_850=0.50, remission_940=0.48, subsurface_bias_mm=5.0, lambertian_exponent=1.0,
            source=f"DragonSkin 30 with skin pigments (Table 5-2). {_SKIN_LIKE}; {_SKIN_BIAS}; Lambertian "
            "because cast on sandpaper 120 to be diffuse (5.4.1)",
        ),
        Material(
            "gelatine", remission_850=0.52, remission_940=0.49, subsurface_bias_mm=5.0, lambertian_exponent=1.0,
            source=f"Kryolan Gelafix (glycerin, water, gelatin; Table 5-2). {_SKIN_LIKE}; {_SKIN_BIAS}; "
            "Lambertian because pressed onto sandpaper 120 (5.4.1)",
        ),
        Material(
            "collagen", remission_850=0.35, remission_940=0.33, subsurface_bias_mm=3.0, lambertian_exponent=2.0,
            source=f"Viscofan COFFI collagen film (Table 5-2). {_SKIN_LIKE}; assumption: a thin semi-transparent "
            "film whose bias is set by what lies behind it, taken as 3 mm; m = 2 because the smooth film "
            "reflects partly specularly, in line with Thesis 2024 (6.5: largest relative loss with angle, "
            "stereo invalid from 20 to 60 deg)",
        ),
        Material(
            "wall", remission_850=0.90, remission_940=0.90, subsurface_bias_mm=0.0, lambertian_exponent=1.0,
            source="Thesis 2024, 4.1.1 and Fig. B-1: the wall is painted white with 90 % reflectance at 850 and 940 nm; "
            "opaque matt paint (bias 0, Lambertian: assumption)",
        ),
        Material(
            "chart_white", remission_850=0.80, remission_940=0.80, subsurface_bias_mm=0.0, lambertian_exponent=1.0,
            source=f"A0 inkjet print, white = the paper (Thesis 2024, 6.2.1). {_PAPER}",
        ),
        Material(
            "chart_black", remission_850=0.0076, remission_940=0.0076, subsurface_bias_mm=0.0, lambertian_exponent=1.0,
            source="water-based inkjet black; Thesis 2024, 6.2.1 and Fig. B-2: black/white about 1:105 in the NIR, "
            "so chart_white / 105",
        ),
        Material(
            "paper_white", remission_850=0.80, remission_940=0.80, subsurface_bias_mm=0.0, lambertian_exponent=1.0,
            source=f"white sheet used as white reference (Thesis 2024, 5.1.2, 6.2.1). {_PAPER}",
        ),
    )
}


def get_material(name: str) -> Material:
    """The material called ``name``; KeyError listing the known names otherwise."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise KeyError(f"unknown material {name!r}; known: {', '.join(MATERIALS)}") from None


def remission(material: Material | str, wavelength_nm: float) -> float:
    """Diffuse NIR reflectance at ``wavelength_nm``, linear through the 850 and 940 nm values.

    ``material`` is a Material or its name. ValueError outside 800-1000 nm.
    """
    m = get_material(material) if isinstance(material, str) else material
    lo, hi = WAVELENGTH_RANGE_NM
    if not lo <= wavelength_nm <= hi:
        raise ValueError(f"wavelength {wavelength_nm} nm is outside the table's {lo:.0f}-{hi:.0f} nm")
    return m.remission_850 + (m.remission_940 - m.remission_850) * (wavelength_nm - 850.0) / 90.0


def angle_factor(material: Material | str, incidence_deg: float | np.ndarray) -> float | np.ndarray:
    """Signal relative to normal incidence, cos(theta)^m, for a surface tilted by ``incidence_deg``.

    Illumination and camera on the same axis; 0 beyond 90 deg (surface seen from behind).
    """
    m = get_material(material) if isinstance(material, str) else material
    return np.clip(np.cos(np.radians(incidence_deg)), 0.0, None) ** m.lambertian_exponent
