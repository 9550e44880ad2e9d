"""``tectum devices``: list the event cameras attached over USB."""

from __future__ import annotations

import argparse
import json

HELP = "list attached USB event cameras (DVS128, DAVIS240/346, DVXplorer); --emulate to try an emulated one"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print the list as JSON")
    p.add_argument("--emulate", metavar="MODEL", action="append", default=[],
                   help="add an emulated camera (dvs128, davis240, davis346, dvxplorer, dvxplorer_lite) "
                        "instead of using libusb")


def main(args: argparse.Namespace) -> int:
    from tectum.sources.usb._device import default_backend, list_devices

    reason = ""
    if args.emulate:
        from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera

        backend = EmulatedBackend(*(EmulatedCamera(m, serial=f"EMU{i:05d}", address=5 + i)
                                    for i, m in enumerate(args.emulate)))
    else:
        backend, reason = default_backend()
    found = []
    if backend is not None:
        try:
            found = list_devices(backend)
        except Exception as e:  # no permission to enumerate, a broken bus
            reason = f"cannot enumerate USB devices: {e}"
        else:
            if not found:
                reason = "no iniVation camera (vendor 152a, products 8400/841a/841b/8419) is attached"
    if args.json:
        print(json.dumps({"devices": [d.as_dict() for d in found], "reason": reason}, indent=1))
        return 0
    for d in found:
        size = f"{d.sensor[0]}x{d.sensor[1]}" if d.sensor else "?"
        print(f"{d.model:<10} {d.chip:<10} serial {d.serial or '?':<10} {size:<8} bus {d.bus} addr {d.address} "
              f"firmware {d.firmware}" + (f"  ERROR: {d.error}" if d.error else ""))
    if not found:
        print(f"no cameras: {reason}")
    return 0
