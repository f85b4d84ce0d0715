"""Laser distance meters giving the reference distance (:class:`~drivers.protocols.RangeMeter`)."""

from drivers.laser.dimetix import DimetixError, DimetixLaser, DimetixTargetError, read_distances

__all__ = ["DimetixError", "DimetixLaser", "DimetixTargetError", "read_distances"]
