"""Two controllers, arbitration and an error counter, on a simulated clock.

Run: .venv/bin/python examples/bus_basics.py
"""

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.common.clock import SimulatedClock


def main() -> None:
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    a = bus.attach("a")
    b = bus.attach("b")
    bus.attach("listener", on_frame=lambda f, t: print(f"{t * 1e6:8.1f} us  {f}"))

    print("three frames queued at the same instant leave lowest id first:")
    a.send(CanFrame(0x300, b"\x03"))
    b.send(CanFrame(0x100, b"\x01"))
    a.send(CanFrame(0x200, b"\x02"))  # behind 0x300 in a's own FIFO queue
    clock.advance(0.01)

    print("\na lone sender (everybody else unplugged) goes error-passive:")
    for ctrl in list(bus.controllers):
        if ctrl is not a:
            bus.disconnect(ctrl)
    a.send(CanFrame(0x123, b"hi"))
    clock.advance(0.01)
    print(f"  {a}")


if __name__ == "__main__":
    main()
