"""``labctl analyze``: metrics on single files, outside any run (README.md, Command line)."""

from __future__ import annotations

from pathlib import Path

import click

from labctl.cli.inputs import POSITIVE
from labctl.cli.outputs import OutputFile, png_file
from labctl.errors import InputError
from labctl.jsondoc import dumps


@click.group("analyze")
def analyze_group() -> None:
    """Analyze single images or point clouds."""


def _unreadable(what: str, path: Path, exc: Exception) -> InputError:
    """Why ``path`` cannot be read; an end of file (which click would report as "aborted") as a short file."""
    if isinstance(exc, EOFError):
        return InputError(f"cannot read {what} {path}: the file ends before its data ({path.stat().st_size} bytes; "
                          "empty or truncated)")
    return InputError(f"cannot read {what} {path}: {exc}")


def _roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or values[2] <= 0 or values[3] <= 0 or min(values[:2]) < 0:
        raise InputError(f"--roi {text!r}: expected X,Y,W,H in whole pixels (W, H > 0)")
    return values  # type: ignore[return-value]


@analyze_group.command("sfr")
@click.argument("image", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--roi", help="region X,Y,W,H in pixels (default: the whole image or the first edge found)")
@click.option("--sfrmat5", is_flag=True, help="no ESF bin correction: reproduce sfrmat5 exactly")
@click.option("--json", "as_json", is_flag=True, help="one JSON document on stdout")
def sfr(image: Path, roi: str | None, sfrmat5: bool, as_json: bool) -> None:
    """ISO 12233 slanted-edge SFR of IMAGE (png, tif, bmp or npy)."""
    from metrics.sfr import analyze_image, load_image

    region = _roi(roi)
    try:
        pixels = load_image(image)
    except (FileNotFoundError, ValueError, OSError, EOFError) as exc:
        raise _unreadable("image", image, exc) from None
    try:
        result = analyze_image(pixels, region, bin_correction=not sfrmat5)
    except ValueError as exc:
        raise InputError(f"{image}: {exc}") from None
    doc = {
        "sfr10": result.sfr10,
        "sfr50": result.sfr50,
        "sfr_area": result.sfr_area,
        "angle_deg": result.angle_deg,
        "orientation": result.orientation,
        "clipped": result.clipped,
        "warnings": list(result.warnings),
        "frequency": [round(float(f), 6) for f in result.frequency],
        "sfr": [round(float(v), 6) for v in result.sfr],
    }
    if as_json:
        click.echo(dumps(doc, indent=None))
        return
    click.echo(f"{image}: {result.orientation} edge at {result.angle_deg:.2f} deg")
    click.echo(f"SFR50 {result.sfr50:.4f} cy/px, SFR10 {result.sfr10:.4f} cy/px, SFR area {result.sfr_area:.4f}")
    for warning in result.warnings:
        click.echo(f"warning: {warning}")


def _fov_deg(text: str) -> tuple[float, float]:
    try:
        values = tuple(float(p) for p in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 2 or not all(0 < v < 180 for v in values):
        raise InputError(f"--fov-deg {text!r}: expected H,V in degrees, each between 0 and 180")
    return values  # type: ignore[return-value]


@analyze_group.command("checkerboard")
@click.argument("image", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--tile-mm", type=POSITIVE, required=True, help="checkerboard tile size in mm")
@click.option("--distance-mm", type=POSITIVE, required=True, help="camera - board distance in mm")
@click.option("--fov-deg", "fov_text", required=True, help="the camera's given FOV H,V in degrees")
@click.option("--cloud", type=click.Path(dir_okay=False, path_type=Path),
              help="organized point cloud of the same view: .pcd, or .npy H x W x 3 in mm, NaN invalid")
@click.option("--plot", "plot_path", type=OutputFile("plot.png"),
              help="write the found and expected corners as a PNG figure")
@click.option("--json", "as_json", is_flag=True, help="one JSON document on stdout")
def checkerboard(image: Path, tile_mm: float, distance_mm: float, fov_text: str, cloud: Path | None,
                 plot_path: Path | None, as_json: bool) -> None:
    """Distortion of a checkerboard IMAGE (png, tif, bmp or npy) and of its CLOUD (Thesis 2024, 5.2, 6.4)."""
    from metrics.distortion import cloud_distortion, detect_corners, distortion, pixel_aspect_distortion_pct, pixel_aspect_ratio
    from metrics.sfr import load_image

    fov = _fov_deg(fov_text)
    if plot_path is not None:
        png_file(plot_path, "--plot")
    try:
        pixels = load_image(image)
    except (FileNotFoundError, ValueError, OSError, EOFError) as exc:
        raise _unreadable("image", image, exc) from None
    points = _organized_cloud(cloud) if cloud is not None else None
    if points is not None and points.shape[:2] != pixels.shape:
        raise InputError(f"cloud {cloud}: {points.shape[0]} x {points.shape[1]} points do not match the image's "
                         f"{pixels.shape[0]} x {pixels.shape[1]} pixels")
    try:
        corners = detect_corners(pixels)
        result = distortion(corners, tile_mm, distance_mm, fov)
        in_cloud = cloud_distortion(points, result.corners, tile_mm, fov) if points is not None else None
    except ValueError as exc:
        raise InputError(f"{image}: {exc}") from None
    height, width = pixels.shape
    doc = {
        "radial_distortion_w_pct": result.radial_distortion_w_pct,
        "radial_distortion_h_pct": result.radial_distortion_h_pct,
        "radial_median_w_pct": result.radial_median_w_pct,
        "radial_median_h_pct": result.radial_median_h_pct,
        "raw_distortion_w_pct": result.raw_distortion_w_pct,
        "raw_distortion_h_pct": result.raw_distortion_h_pct,
        "raw_median_w_pct": result.raw_median_w_pct,
        "raw_median_h_pct": result.raw_median_h_pct,
        "fov_estimate_deg": list(result.fov_estimate_deg),
        "k1": result.k1,
        "linear_scale": list(result.linear_scale),
        "rotation_deg": result.rotation_deg,
        "fit_rms_px": result.fit_rms_px,
        "pixel_aspect_ratio": pixel_aspect_ratio(*fov, width, height),
        "pixel_aspect_distortion_pct": pixel_aspect_distortion_pct(*fov, width, height),
        "n_corners": result.n_corners,
        "detector": corners.detector,
        "warnings": list(result.warnings),
    }
    if in_cloud is not None:
        doc.update({
            "cloud_distortion_w_pct": in_cloud.distortion_w_pct,
            "cloud_distortion_h_pct": in_cloud.distortion_h_pct,
            "cloud_median_w_pct": in_cloud.median_w_pct,
            "cloud_median_h_pct": in_cloud.median_h_pct,
            "cloud_n_corners": in_cloud.n_corners,
        })
        doc["warnings"] += list(in_cloud.warnings)
    if plot_path is not None:
        from labctl.report.plots.distortion import plot_distortion

        plot_distortion(pixels, result, plot_path, in_cloud, title=str(image))
    if as_json:
        click.echo(dumps(doc, indent=None))
        return
    click.echo(f"{image}: {result.n_corners} corners ({corners.detector} detector)")
    click.echo(f"distortion (max, width / height): raw {result.raw_distortion_w_pct:+.2f} / "
               f"{result.raw_distortion_h_pct:+.2f} %, radial {result.radial_distortion_w_pct:+.2f} / "
               f"{result.radial_distortion_h_pct:+.2f} % (median {result.radial_median_w_pct:.2f} / "
               f"{result.radial_median_h_pct:.2f} %)")
    click.echo(f"FOV estimate {result.fov_estimate_deg[0]:.2f} x {result.fov_estimate_deg[1]:.2f} deg, "
               f"k1 {result.k1:+.4f}, pixel aspect distortion {doc['pixel_aspect_distortion_pct']:.1f} %")
    if in_cloud is not None:
        click.echo(f"point cloud: {in_cloud.distortion_w_pct:+.2f} / {in_cloud.distortion_h_pct:+.2f} % "
                   f"(median {in_cloud.median_w_pct:.2f} / {in_cloud.median_h_pct:.2f} %)")
    for warning in doc["warnings"]:
        click.echo(f"warning: {warning}")


def _organized_cloud(path: Path):
    """An organized H x W x 3 cloud in mm from a .npy array or a .pcd file (NaN = invalid)."""
    import numpy as np

    from labctl.report.pointcloud_io import read_pcd

    if not path.is_file():
        raise InputError(f"cloud file not found: {path}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            cloud = np.load(path, allow_pickle=False)
        elif suffix == ".pcd":
            cloud = read_pcd(path).xyz
        else:
            raise InputError(f"cloud {path}: unsupported type {suffix!r}; use .pcd or .npy (H x W x 3 in mm)")
    except (ValueError, OSError, UnicodeDecodeError, EOFError) as exc:
        raise _unreadable("cloud", path, exc) from None
    if cloud.ndim != 3 or cloud.shape[2] != 3 or cloud.shape[0] < 2 or not np.issubdtype(cloud.dtype, np.number):
        raise InputError(f"cloud {path}: shape {cloud.shape} is not an organized H x W x 3 cloud (x, y, z in mm)")
    return cloud.astype(float)


@analyze_group.command("boehler")
@click.argument("cloud", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--segments", type=int, required=True, help="segments of the star (72 or 24)")
@click.option("--inlier-mm", type=POSITIVE, default=20.0, show_default=True, help="star inliers: distance to its plane")
@click.option("--binning", "binning_text", default="auto", show_default=True,
              help="1 mm rings evaluated together: a number, or auto (2, more where the points lie further apart)")
@click.option("--fov-deg", "fov_text", help="the camera's FOV H,V in degrees: the sensor resolution not to beat")
@click.option("--plot", "plot_path", type=OutputFile("plot.png"),
              help="write the star and its clusters per ring as a PNG figure")
@click.option("--json", "as_json", is_flag=True, help="one JSON document on stdout")
def boehler(cloud: Path, segments: int, inlier_mm: float, binning_text: str, fov_text: str | None,
            plot_path: Path | None, as_json: bool) -> None:
    """Böhler-star resolution of an organized point CLOUD (.pcd or .npy; Thesis 2024, 5.1.3)."""
    from metrics.boehler import analyze_boehler

    fov = _fov_deg(fov_text) if fov_text is not None else None
    if plot_path is not None:
        png_file(plot_path, "--plot")
    if segments < 16 or segments % 2:
        raise InputError(f"--segments {segments}: a Böhler star has an even number of segments (72 or 24)")
    binning = None if binning_text == "auto" else (int(binning_text) if binning_text.isdigit() else 0)
    if binning is not None and binning < 1:
        raise InputError(f"--binning {binning_text}: must be auto or a whole number of at least 1")
    points = _organized_cloud(cloud)
    try:
        result = analyze_boehler(points, segments, inlier_mm=inlier_mm, binning=binning, fov_deg=fov)
    except ValueError as exc:
        raise InputError(f"{cloud}: {exc}") from None
    if plot_path is not None:
        from labctl.report.plots.boehler import plot_boehler

        plot_boehler(result, points, plot_path)
    doc = {
        "resolution_h_mm": result.resolution_h_mm,
        "resolution_v_mm": result.resolution_v_mm,
        "resolution_mm": result.resolution_mm,
        "radius_h_mm": result.radius_h_mm,
        "radius_v_mm": result.radius_v_mm,
        "angular_h_deg": result.angular_h_deg,
        "angular_v_deg": result.angular_v_deg,
        "sensor_h_mm": result.sensor_h_mm,
        "sensor_v_mm": result.sensor_v_mm,
        "clamped_h": result.clamped_h,
        "clamped_v": result.clamped_v,
        "segments": result.segments,
        "star_found": result.star_found,
        "modulation": result.modulation,
        "distance_mm": result.distance_mm,
        "centre_mm": list(result.centre_mm),
        "normal": list(result.normal),
        "star_radius_mm": result.star_radius_mm,
        "ring_width_mm": result.ring_width_mm,
        "warnings": list(result.warnings),
        "rings": {
            "radius_mm": result.radii_mm.tolist(),
            "clusters": result.clusters.tolist(),
            "clusters_h": result.clusters_h.tolist(),
            "clusters_v": result.clusters_v.tolist(),
            "expected_h": result.expected_h,
            "expected_v": result.expected_v,
            "resolved_h": result.resolved_h.tolist(),
            "resolved_v": result.resolved_v.tolist(),
        },
    }
    if as_json:
        click.echo(dumps(doc, indent=None))
        return
    x, y, z = result.centre_mm
    click.echo(f"{cloud}: {segments}-segment star at {result.distance_mm:.0f} mm, centre ({x:.1f}, {y:.1f}, {z:.1f}) mm"
               if result.star_found else
               f"{cloud}: no {segments}-segment star found on the nearest plane facing the camera ({result.distance_mm:.0f} mm)")
    for name, radius, lateral, angular in (("horizontal", result.radius_h_mm, result.resolution_h_mm, result.angular_h_deg),
                                           ("vertical", result.radius_v_mm, result.resolution_v_mm, result.angular_v_deg)):
        click.echo(f"{name}: not resolved" if radius != radius else
                   f"{name}: r = {radius:.0f} mm, lateral {lateral:.2f} mm, angular {angular:.3f} deg")
    for warning in result.warnings:
        click.echo(f"warning: {warning}")
