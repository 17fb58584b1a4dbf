"""``kind = "esi"``: an EtherCAT slave from its ESI file (docs/bring-your-own-network.md)."""

__all__ = []
