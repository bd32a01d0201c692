"""Test helpers shipped with the package, so users can test their own code against them:
a scripted MAVLink vehicle, a fake autopilot and a contract checker for any
:class:`~companion.link.base.VehicleLink` backend."""

from companion.testing.fake_vehicle import FakeVehicle, Received

__all__ = ["FakeVehicle", "Received"]
