"""The lab's targets as scenes (one per procedure of docs/campaign.md).

Stage lab (camera at the origin looking along +z, wall at z = D):

* ``wall`` — the 90 % white wall filling the view;
* ``slanted_edge`` — an A0 inkjet chart (1189 x 841 mm) on the wall: white paper
  with a black quadrant whose two edges leave the chart centre slanted by
  ``angle_deg`` (default 8 deg, Thesis 2024, 6.2.1), so that one near-vertical and
  one near-horizontal edge are in view at every distance;
* ``white_sheet`` — the same chart covered by a white sheet (white reference);
* ``checkerboard`` — a printed board of ``tile_mm`` tiles (default 19 mm) on
  the wall, a tile corner on the optical axis;
* ``boehler_star`` — a Boehler star (``diameter_mm`` 400, ``segments`` 72 or
  24 of which half are filled, a ``disc_mm`` 10 mm central disc) standing
  ``gap_mm`` in front of the wall, centred ``offset_mm`` off the optical axis
  and turned by ``rotation_deg``;
* ``face_mask`` — a silicone face mask (height field) ``gap_mm`` in front of the wall;
* ``ball_bar`` — the VDI/VDE 2634-2 ball bar: two matte white spheres of
  ``diameter_mm`` whose centres are ``spacing_mm`` apart, the bar's centre
  ``gap_mm`` in front of the wall and ``offset_mm`` off the optical axis,
  turned by ``orientation_deg`` in the image plane (0: horizontal) and
  ``tilt_deg`` out of it (about the bar's perpendicular in the image plane: the
  far sphere further away); the thin bar between them is not rendered;
* ``flat_plate`` — a matte white ``plate_mm`` flat plate ``gap_mm`` in front of
  the wall, tilted by ``tilt_deg`` about the vertical axis.

Robot lab (circle centre at the origin, Fig. 5-15): a ``plate_mm`` square plate
of a material (``ptfe``, ``molleton``, ``silicone``, ``gelatine``,
``collagen``) facing the 0 deg camera, ``offset_mm`` behind the circle centre
(target misalignment), black molleton curtains 2 m behind.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np

from sim.materials import get_material, remission
from sim.scenes.base import HeightFieldSurface, PlaneSurface, Scene, SphereSurface, uniform
from sim.scenes.patterns import Checker, Rect, Shape, SlantedQuadrant, Star, Texture

A0_MM = (1189.0, 841.0)
MASK_HALF_EXTENT_MM = (90.0, 120.0)  # the face mask's outline (about 150 x 210 mm) with a margin
X, Y, Z = np.eye(3)
PLATE_MATERIALS = ("ptfe", "molleton", "silicone", "gelatine", "collagen")


def _frontal_plane(distance_mm: float, texture: Texture, material: str, shape: Shape | None = None,
                   centre: tuple[float, float] = (0.0, 0.0)) -> PlaneSurface:
    """A plane z = distance facing the stage camera, in-plane axes along world x and y."""
    return PlaneSurface(np.array([centre[0], centre[1], distance_mm]), X, Y, texture, material, shape)


def _rect(width: float, height: float) -> Rect:
    return Rect(width, height)


def _wall(distance_mm: float, wavelength_nm: float) -> PlaneSurface:
    return _frontal_plane(distance_mm, uniform(remission("wall", wavelength_nm)), "wall")


def wall_scene(distance_mm: float, wavelength_nm: float, **_: Any) -> Scene:
    return Scene().add(_wall(distance_mm, wavelength_nm))


def chart_scene(distance_mm: float, wavelength_nm: float, angle_deg: float = 8.0,
                offset_mm: tuple[float, float] = (0.0, 0.0), white: bool = False, **_: Any) -> Scene:
    """Slanted-edge chart (or its white reference) on the wall."""
    texture = SlantedQuadrant(angle_deg, remission("chart_white", wavelength_nm), remission("chart_black", wavelength_nm))
    sheet = (uniform(remission("paper_white", wavelength_nm)), "paper_white") if white else (texture, "chart_white")
    return (
        Scene()
        .add(_frontal_plane(distance_mm - 0.2, sheet[0], sheet[1], _rect(*A0_MM), centre=offset_mm))
        .add(_wall(distance_mm, wavelength_nm))
    )


def checkerboard_scene(distance_mm: float, wavelength_nm: float, tile_mm: float = 19.0,
                       board_mm: tuple[float, float] = (1200.0, 900.0),
                       offset_mm: tuple[float, float] = (0.0, 0.0), **_: Any) -> Scene:
    """Printed checkerboard on the wall, a tile corner at the board centre."""
    texture = Checker(tile_mm, remission("chart_white", wavelength_nm), remission("chart_black", wavelength_nm))

    return (
        Scene()
        .add(_frontal_plane(distance_mm - 0.2, texture, "chart_white", _rect(*board_mm), centre=offset_mm))
        .add(_wall(distance_mm, wavelength_nm))
    )


def boehler_scene(distance_mm: float, wavelength_nm: float, segments: int = 72, gap_mm: float = 300.0,
                  diameter_mm: float = 400.0, disc_mm: float = 10.0, rotation_deg: float = 0.0,
                  offset_mm: tuple[float, float] = (0.0, 0.0), **_: Any) -> Scene:
    """Boehler star ``gap_mm`` in front of the wall at ``distance_mm`` (24 wedges: PTFE; 72: Delrin painted
    white, for which the table's ``paper_white`` stands in)."""
    material = "ptfe" if segments == 24 else "paper_white"
    shape = Star(segments, diameter_mm, disc_mm, rotation_deg)
    star = _frontal_plane(distance_mm - gap_mm, uniform(remission(material, wavelength_nm)), material,
                          shape, centre=offset_mm)
    return Scene().add(star).add(_wall(distance_mm, wavelength_nm))


def face_mask_scene(distance_mm: float, wavelength_nm: float, gap_mm: float = 300.0, **_: Any) -> Scene:
    """Silicone face mask whose base plane stands ``gap_mm`` in front of the wall."""
    from sim.face_mask import face_height

    base = _frontal_plane(distance_mm - gap_mm, uniform(remission("silicone", wavelength_nm)), "silicone")
    mask = HeightFieldSurface(base, face_height, half_extent_mm=(MASK_HALF_EXTENT_MM))
    return Scene().add(mask).add(_wall(distance_mm, wavelength_nm))


#: material of the ball bar's spheres and of the flat plate (matte white, like the wall's paint)
ARTEFACT_MATERIAL = "wall"


def ball_bar_centres(distance_mm: float, spacing_mm: float, gap_mm: float, orientation_deg: float,
                     tilt_deg: float, offset_mm: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the ball bar's two spheres (camera frame, wall at z = distance_mm)."""
    phi, tilt = np.radians(orientation_deg), np.radians(tilt_deg)
    axis = np.array([np.cos(phi) * np.cos(tilt), np.sin(phi) * np.cos(tilt), np.sin(tilt)])
    middle = np.array([offset_mm[0], offset_mm[1], distance_mm - gap_mm])
    return middle - axis * spacing_mm / 2, middle + axis * spacing_mm / 2


def ball_bar_scene(distance_mm: float, wavelength_nm: float, diameter_mm: float = 50.0, spacing_mm: float = 300.0,
                   gap_mm: float = 500.0, orientation_deg: float = 0.0, tilt_deg: float = 0.0,
                   offset_mm: tuple[float, float] = (0.0, 0.0), **_: Any) -> Scene:
    """Ball bar ``gap_mm`` in front of the wall at ``distance_mm``."""
    texture = uniform(remission(ARTEFACT_MATERIAL, wavelength_nm))
    scene = Scene()
    for centre in ball_bar_centres(distance_mm, spacing_mm, gap_mm, orientation_deg, tilt_deg, tuple(offset_mm)):
        scene.add(SphereSurface(centre, diameter_mm / 2, texture, ARTEFACT_MATERIAL))
    return scene.add(_wall(distance_mm, wavelength_nm))


def flat_plate_scene(distance_mm: float, wavelength_nm: float, plate_mm: tuple[float, float] = (500.0, 400.0),
                     gap_mm: float = 500.0, tilt_deg: float = 0.0, **_: Any) -> Scene:
    """Flat plate ``gap_mm`` in front of the wall, tilted about the vertical axis by ``tilt_deg``."""
    tilt = np.radians(tilt_deg)
    u_axis = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    plate = PlaneSurface(np.array([0.0, 0.0, distance_mm - gap_mm]), u_axis, Y,
                         uniform(remission(ARTEFACT_MATERIAL, wavelength_nm)), ARTEFACT_MATERIAL, _rect(*plate_mm))
    return Scene().add(plate).add(_wall(distance_mm, wavelength_nm))


def plate_scene(material: str, wavelength_nm: float, plate_mm: float = 200.0, offset_mm: float = 0.0,
                **_: Any) -> Scene:
    """Robot lab: a material plate at the circle centre (``offset_mm`` behind it), curtains behind."""
    get_material(material)
    plate = PlaneSurface(np.array([0.0, 0.0, offset_mm]), X, Y, uniform(remission(material, wavelength_nm)),
                         material, _rect(plate_mm, plate_mm))
    curtain = PlaneSurface(np.array([0.0, 0.0, 2000.0]), X, Y, uniform(remission("molleton", wavelength_nm)),
                           "molleton")
    return Scene().add(plate).add(curtain)


STAGE_TARGETS = {
    "wall": wall_scene,
    "slanted_edge": chart_scene,
    "white_sheet": lambda d, wl, **kw: chart_scene(d, wl, white=True, **kw),
    "checkerboard": checkerboard_scene,
    "boehler_star": boehler_scene,
    "face_mask": face_mask_scene,
    "ball_bar": ball_bar_scene,
    "flat_plate": flat_plate_scene,
}
TARGETS = (*STAGE_TARGETS, *PLATE_MATERIALS)


def build_scene(target: str, params: Mapping[str, Any], wavelength_nm: float, distance_mm: float) -> Scene:
    """The scene of ``target``; ``distance_mm`` is the camera-wall distance (stage lab)."""
    if target in STAGE_TARGETS:
        return STAGE_TARGETS[target](distance_mm, wavelength_nm, **params)
    if target in PLATE_MATERIALS:
        return plate_scene(target, wavelength_nm, **params)
    raise KeyError(f"no simulated scene for target {target!r}; known: {', '.join(TARGETS)}")


def scene_parameters(target: str) -> dict[str, Any]:
    """The parameters ``build_scene`` (or ``plate_scene``) takes for ``target``, each with its default; the
    distance, the wavelength, the chart's white cover and a plate's offset (from the model) are not among them."""
    if target in PLATE_MATERIALS:
        builder, fixed = plate_scene, {"material", "wavelength_nm", "offset_mm"}
    elif target == "white_sheet":
        builder, fixed = chart_scene, {"distance_mm", "wavelength_nm", "white"}
    elif target in STAGE_TARGETS:
        builder, fixed = STAGE_TARGETS[target], {"distance_mm", "wavelength_nm"}
    else:
        raise KeyError(f"no simulated scene for target {target!r}; known: {', '.join(TARGETS)}")
    return {name: param.default for name, param in inspect.signature(builder).parameters.items()
            if name not in fixed and param.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD}
