"""Host side of the maxon USB protocol: ``IdxClient`` over pyserial or pyusb, and the ``idx`` CLI."""
