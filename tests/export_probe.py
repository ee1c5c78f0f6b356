"""pysoem driven by a module of ``ecatcfg export --format pysoem``, in its own process
inside the test's network namespace: ``python export_probe.py IFACE MODULE.py JSON``; prints
one JSON object.

The user's sequence from the module's docstring: config_init, the module's setup, then
config_map (the module's, which checks SOEM's sizes); then SAFEOP, OP, ``cycles`` process data cycles (the working counters seen
in ``wkcs``), SDO uploads of ``read``
([[slave, index, subindex], ...]) as hex, and each slave's DC activation and SYNC0
cycle registers in ``dc``.  ``setup_error`` holds the module's SetupError from ``setup``, ``map_error`` from
``config_map`` (a refused step, or SOEM's sizes not the ENI's).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time

import pysoem
from soem_patience import be_patient

STATE_TIMEOUT_US = 10_000_000      # a loaded 2-core machine: margin over the ~0.1 s needed


def main() -> None:
    iface, module_path, options = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
    spec = importlib.util.spec_from_file_location("exported", module_path)
    assert spec is not None and spec.loader is not None
    exported = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(exported)
    be_patient(pysoem)
    master = pysoem.Master()
    master.open(iface)
    result: dict = {}
    try:
        result["found"] = master.config_init()
        try:
            exported.setup(master)
        except exported.SetupError as exc:
            result["setup_error"] = str(exc)
            return
        try:
            result["iomap"] = exported.config_map(master)
        except exported.SetupError as exc:
            result["map_error"] = str(exc)
            return
        result["sizes"] = [(len(s.output), len(s.input)) for s in master.slaves]
        master.state = pysoem.SAFEOP_STATE
        master.write_state()
        result["safeop"] = master.state_check(pysoem.SAFEOP_STATE, STATE_TIMEOUT_US)
        master.read_state()
        result["al"] = [(s.state, s.al_status) for s in master.slaves]
        if result["safeop"] != pysoem.SAFEOP_STATE:
            return
        master.send_processdata()
        master.receive_processdata(10_000)
        master.state = pysoem.OP_STATE
        master.write_state()
        for _ in range(400):
            master.send_processdata()
            master.receive_processdata(10_000)
            if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        wkcs = []
        for _ in range(options.get("cycles", 20)):
            master.send_processdata()
            wkcs.append(master.receive_processdata(10_000))
            time.sleep(0.001)
        result["op"] = master.read_state()
        result["wkcs"] = sorted(set(wkcs))
        result["read"] = [master.slaves[n].sdo_read(index, sub).hex()
                          for n, index, sub in options.get("read", [])]
        # Each slave's DC activation (0x0981) and SYNC0 cycle time (0x09A0) in OP.
        result["dc"] = [(s._fprd(0x0981, 1).hex(), s._fprd(0x09A0, 4)[::-1].hex())
                        for s in master.slaves]
        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
