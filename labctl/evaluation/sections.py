"""The procedure sections of keyfigures.json (docs/keyfigures.md) as typed records: one place to read their shape.

Each table of the document is a list of rows; a row is a ``TypedDict`` (a
mapping, as the report's tables read it) whose keys are the table's columns in
the order keyfigures.json writes them. Every table's columns are fixed. The
single-object sections (``alignment``, an ``acceptance_test`` verdict,
``misalignment``, ``face_mask``) are ``TypedDict`` records as well. A number is
None in the document where it was not measured: the evaluation's NaN, written
as null (``labctl/jsondoc.py``).
"""

from __future__ import annotations

from typing import TypedDict


class DepthSweepRow(TypedDict):
    """A row of ``depth_sweep``: one wall step's depth errors (mm; ``invalid_fraction`` 0 to 1)."""

    step: str
    reference_mm: float | None
    trueness_median_mm: float | None
    trueness_q90_mm: float | None
    accuracy_median_mm: float | None
    accuracy_q90_mm: float | None
    precision_median_mm: float | None
    precision_q90_mm: float | None
    repeatability_center_mm: float | None
    invalid_fraction: float | None


class SlantedEdgeRow(TypedDict):
    """A row of ``slanted_edge``: one chart position's SFR figures and imagery resolution (angular and lateral),
    per orientation (``_h`` horizontal, ``_v`` vertical); ``note_*`` says why an edge is not valid (empty when
    it is)."""

    distance_mm: float
    step: str
    sfr10_h: float | None
    sfr50_h: float | None
    sfr_area_h: float | None
    valid_h: bool
    resolution_h_deg: float | None
    resolution_h_mm: float | None
    note_h: str
    sfr10_v: float | None
    sfr50_v: float | None
    sfr_area_v: float | None
    valid_v: bool
    resolution_v_deg: float | None
    resolution_v_mm: float | None
    note_v: str


class CaptureRow(TypedDict):
    """A row of ``capture``: one step of ``labctl device camera``; the plane's figures are None unless the
    scene is planar (its inlier fraction None without a plane)."""

    step: str
    frames: int
    valid_fraction: float | None
    depth_median_mm: float | None
    depth_q05_mm: float | None
    depth_q95_mm: float | None
    temporal_noise_median_mm: float | None
    temporal_noise_q90_mm: float | None
    planar: bool
    plane_inlier_fraction: float | None
    plane_distance_on_axis_mm: float | None
    plane_tilt_about_x_deg: float | None
    plane_tilt_about_y_deg: float | None
    plane_rms_mm: float | None


class AlignmentSection(TypedDict):
    """``alignment``: the accepted ``alignment`` step, the mean x, y, z (mm) of each corner field by name and
    the residual tilt about x (up) and y (right)."""

    step: str
    fields_mm: dict[str, list[float | None]]
    tilt_x_deg: float | None
    tilt_y_deg: float | None


class DepthQualityRow(TypedDict):
    """A row of ``depth_quality``: one wall step's datasheet-comparable figures (``subpixel_rms_px`` None but
    for stereo cameras): ``reference_mm`` is the step's offset-calibrated reference distance,
    ``absolute_reference_mm`` the distance from the camera's depth origin that ``z_accuracy_pct`` is measured
    against (both None without it)."""

    step: str
    reference_mm: float | None
    absolute_reference_mm: float | None
    fill_rate_pct: float | None
    z_accuracy_pct: float | None
    plane_fit_rms_mm: float | None
    plane_fit_rms_pct: float | None
    subpixel_rms_px: float | None
    spatial_precision_mm: float | None
    temporal_precision_mm: float | None


class AcceptanceVerdict(TypedDict):
    """A quantity of ``acceptance_test`` (VDI/VDE 2634-2): its figure (mm), the campaign's maximum permissible
    error (None when it gives none), ``pass``, ``fail`` or ``marginal`` (within the figure's expanded uncertainty
    of the MPE) or ``no_mpe``, that expanded uncertainty (mm, None: not estimated) and what it rests on
    (``uncertainty_basis``), the frames averaged into each
    measurement (None when its positions average different numbers); ``deviation`` says where the quantity departs
    from the guideline (the sphere fits' rim rule; None for the plate's flatness)."""

    value: float | None
    mpe_mm: float | None
    verdict: str
    expanded_uncertainty_mm: float | None
    uncertainty_basis: str
    frames_per_measurement: int | None
    deviation: str | None


class AcceptancePositionRow(TypedDict):
    """A row of ``acceptance_positions``: one sphere-bar or flat-plate step, its frames evaluated, its
    measurements, the frames averaged into each and, per VDI/VDE 2634-2 quantity, the measurement of largest
    magnitude (None where the step does not measure it), and ``points_used``: per measurement, per sphere the share
    of its points the fit used (rim rule and 0.3 % rule; None for the plate); ``pose_deg`` is the bar's
    orientation or the plate's tilt; the placement (VDI/VDE 2634-2: positions spread through the measuring
    volume): ``offset_mm`` the artefact's middle right of and above the camera axis, ``orientation_deg`` the
    bar's direction in the image plane (None for the plate), ``tilt_deg`` the bar's tilt towards the wall or
    the plate's tilt about the vertical."""

    step: str
    distance_mm: float
    pose_deg: float
    offset_mm: list[float]
    orientation_deg: float | None
    tilt_deg: float
    frames: float
    measurements: float
    frames_per_measurement: float
    probing_error_form_mm: float | None
    probing_error_size_mm: float | None
    sphere_spacing_error_mm: float | None
    flatness_error_mm: float | None
    points_used: list[list[float]] | None


class CheckerboardRow(TypedDict):
    """A row of ``checkerboard``: the distortion of the ``intensity`` image or of the ``point cloud``; the FOV
    estimate and ``k1`` are None for the point cloud."""

    image: str
    raw_w_pct: float | None
    raw_h_pct: float | None
    radial_w_pct: float | None
    radial_h_pct: float | None
    median_w_pct: float | None
    median_h_pct: float | None
    fov_estimate_h_deg: float | None
    fov_estimate_v_deg: float | None
    k1: float | None
    corners: int


class BoehlerStarRow(TypedDict):
    """A row of ``boehler_star``: one star (``"<segments> segments (<step>)"``), where it was placed and the
    point cloud's resolution on it, lateral and angular."""

    star: str
    placed_mm: float | None
    resolution_h_mm: float | None
    resolution_v_mm: float | None
    angular_h_deg: float | None
    angular_v_deg: float | None
    distance_mm: float | None


class XYNoiseRow(TypedDict):
    """A row of ``xy_noise``: one wall step's x and y noise, at the centre pixel, off axis and as Q90."""

    step: str
    distance_mm: float | None
    repeatability_center_x_mm: float | None
    repeatability_center_y_mm: float | None
    repeatability_off_axis_x_mm: float | None
    repeatability_off_axis_y_mm: float | None
    precision_q90_x_mm: float | None
    precision_q90_y_mm: float | None


class RemissionAngleRow(TypedDict):
    """A row of ``remission_angle``: one material at one angle of incidence, the plate's distance along the
    axis, repeatability, fractions and trueness against the commanded radius (``zero``) and the geometric
    reference."""

    step: str
    material: str
    angle_deg: float
    radius_mm: float
    on_target: bool
    distance_mm: float | None
    distance_se_mm: float | None
    repeatability_mm: float | None
    plane_rms_mm: float | None
    invalid_fraction: float | None
    off_target_fraction: float | None
    trueness_zero_mm: float | None
    reference_mm: float | None
    trueness_geometric_mm: float | None


class Misalignment(TypedDict):
    """``misalignment``: the target and camera-axis offsets and the level fitted to one material's trueness over
    the angles (mm, with standard errors), the fit's residual RMS and its number of angles."""

    material: str
    target_offset_mm: float | None
    target_offset_se_mm: float | None
    camera_axis_offset_mm: float | None
    camera_axis_offset_se_mm: float | None
    bias_mm: float | None
    bias_se_mm: float | None
    residual_rms_mm: float | None
    angles: int


class FaceMaskSection(TypedDict):
    """``face_mask``: the step, the organized point cloud written beside keyfigures.json and its share of
    invalid points."""

    step: str
    pcd: str
    invalid_fraction: float
