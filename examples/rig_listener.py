"""Print and explain every frame on a bus of a running `gatewaylab run` (another process).

Run: gatewaylab run --ready-file ready.json &   then   python examples/rig_listener.py ready.json
"""

import json
import sys
from pathlib import Path

import can

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.explain import explain


def main() -> None:
    info = json.loads(Path(sys.argv[1] if len(sys.argv) > 1 else "ready.json").read_text())
    endpoint = info["buses"]["can0"]["endpoint"]
    with can.Bus(interface="gatewaylab", channel=endpoint, name="listener") as bus:
        for msg in bus:
            if not msg.is_error_frame:
                frame = CanFrame.from_message(msg)
                print(f"{msg.timestamp:12.6f}  {frame!s:<28} {explain(frame)}")


if __name__ == "__main__":
    main()
