"""The esd fixtures (defined in ``esd_fixtures``, shared with tests/hosts/esd_can_ethercat)."""

from esd_fixtures import clock, esd_veth, kit, kit_factory

__all__ = ["clock", "esd_veth", "kit", "kit_factory"]
