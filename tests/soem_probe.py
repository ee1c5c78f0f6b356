"""SOEM (pysoem) as an independent master, run in its own process inside the test's network
namespace: ``python soem_probe.py IFACE JSON_OPTIONS``; prints one JSON object.

Options: ``outputs`` (hex, written to every slave with outputs once in SAFEOP and OP),
``assign`` ({"slave": N, "index": 0x1C13, "pdos": [...]}: after config_map, i.e. after
SOEM sized the SyncManagers, the slave goes back to PREOP and gets this PDO assignment by
SDO download), ``cycles`` (process
data cycles in OP), ``writes`` ([[slave, index, subindex, hex, complete_access], ...]: SDO
downloads in PREOP after config_init, before config_map reads the PDO configuration, as a
SOEM user configures a slave whose mapping the master chooses; aborts in ``writes``),
``read`` ([[slave, index, subindex], ...]: SDO uploads after config_map,
as hex in ``read``), ``dc`` (true: SOEM's ``config_dc`` after config_map, which works out
the tree from the DL statuses and writes each slave's propagation delay; read back from
0x0928 into ``delays``), ``sii_words`` (N: read the first N SII words of every slave with
SOEM's EEPROM reader into ``sii`` (hex) and register 0x0012 into ``alias``, then stop), ``foe`` ([[slave, "write" | "read", name, password, hex
or maximum size], ...]: SOEM's FoE client (ecx_FOEwrite / ecx_FOEread) in PREOP after
config_init, results in ``foe``: {"result": SOEM's return value, "hex": what a read
returned} or {"error": the exception}; then stop).
"""

from __future__ import annotations

import json
import struct
import sys
import time

import pysoem
from soem_patience import be_patient

STATE_TIMEOUT_US = 2_000_000


def main() -> None:
    iface, options = sys.argv[1], json.loads(sys.argv[2] if len(sys.argv) > 2 else "{}")
    be_patient(pysoem)
    master = pysoem.Master()
    master.open(iface)
    result: dict = {}
    try:
        start = time.monotonic()
        found = master.config_init()
        result["found"] = found
        result["init_s"] = round(time.monotonic() - start, 3)
        result["slaves"] = [{"name": s.name, "vendor": s.man, "product": s.id,
                             "revision": s.rev} for s in master.slaves]
        if found <= 0:
            return
        if "foe" in options:
            result["foe"] = []
            for slave, action, name, password, arg in options["foe"]:
                target = master.slaves[slave]
                try:
                    if action == "write":
                        got = {"result": target.foe_write(name, password,
                                                          bytes.fromhex(arg))}
                    else:
                        got = {"hex": target.foe_read(name, password, arg).hex()}
                except Exception as exc:          # pysoem's errors, reported as they are
                    got = {"error": f"{type(exc).__name__}: {exc}"}
                result["foe"].append(got)
            return
        if "sii_words" in options:
            # SOEM's own EEPROM reader (ecx_readeeprom, 4 bytes per read) over the first
            # ``sii_words`` words of every slave, and the alias register 0x0012 as
            # config_init leaves it; nothing else.
            n = options["sii_words"]
            result["sii"] = [b"".join(s.eeprom_read(w) for w in range(0, n, 2))[:2 * n].hex()
                             for s in master.slaves]
            result["alias"] = [struct.unpack("<H", s._fprd(0x0012, 2))[0]
                               for s in master.slaves]
            return
        if "od" in options:
            # SOEM's SDO Information client (ecx_readODlist, ecx_readODdescription,
            # ecx_readOE) over the dictionary of slave ``od``; nothing else.
            result["od"] = [{"index": o.index, "data_type": o.data_type,
                             "object_code": o.object_code, "name": o.name.decode(),
                             # a VAR: its one entry's bit length and access (pysoem gives
                             # a VAR no entry list)
                             "bit_length": o.bit_length, "access": o.obj_access,
                             "entries": [{"data_type": e.data_type,
                                          "bit_length": e.bit_length,
                                          "access": e.obj_access, "name": e.name.decode()}
                                         for e in o.entries]}
                            for o in master.slaves[options["od"]].od]
            return
        if options.get("writes"):
            # config_init leaves the slaves in PREOP: the mailbox works, PDOs are writable.
            done = []
            for n, index, sub, data, ca in options["writes"]:
                try:
                    master.slaves[n].sdo_write(index, sub, bytes.fromhex(data), ca)
                    done.append("ok")
                except pysoem.SdoError as exc:
                    done.append(f"abort 0x{exc.abort_code:08X}")
            result["writes"] = done
        result["iomap"] = master.config_map()
        result["sizes"] = [(len(s.output), len(s.input)) for s in master.slaves]
        result["read"] = [master.slaves[n].sdo_read(index, sub).hex()
                          for n, index, sub in options.get("read", [])]
        # Complete access (SOEM's own request, from subindex 0 or 1), written then read.
        for n, index, sub, data in options.get("ca_write", []):
            master.slaves[n].sdo_write(index, sub, bytes.fromhex(data), ca=True)
        result["ca_read"] = [master.slaves[n].sdo_read(index, sub, ca=True).hex()
                             for n, index, sub in options.get("ca_read", [])]
        if options.get("dc"):
            result["dc"] = bool(master.config_dc())
            result["delays"] = [struct.unpack("<I", s._fprd(0x0928, 4))[0]
                                for s in master.slaves]
        assign = options.get("assign")
        if assign:
            # config_map ends by requesting SAFEOP; PDO assignment is writable in PREOP.
            slave = master.slaves[assign["slave"]]
            slave.state = pysoem.PREOP_STATE
            slave.write_state()
            result["back_to_preop"] = slave.state_check(pysoem.PREOP_STATE, STATE_TIMEOUT_US)
            pdos = assign["pdos"]
            try:
                slave.sdo_write(assign["index"], 0, b"\x00")
                for i, pdo in enumerate(pdos, 1):
                    slave.sdo_write(assign["index"], i, struct.pack("<H", pdo))
                slave.sdo_write(assign["index"], 0, bytes([len(pdos)]))
                result["assign"] = "written"
            except pysoem.SdoError as exc:
                result["assign"] = f"abort 0x{exc.abort_code:08X}"
        master.state = pysoem.SAFEOP_STATE
        master.write_state()
        result["safeop"] = master.state_check(pysoem.SAFEOP_STATE, STATE_TIMEOUT_US)
        master.read_state()
        result["al"] = [(s.state, s.al_status) for s in master.slaves]
        if result["safeop"] != pysoem.SAFEOP_STATE:
            return
        pattern = bytes.fromhex(options.get("outputs", ""))
        for s in master.slaves:
            if len(s.output) and pattern:
                s.output = (pattern * len(s.output))[:len(s.output)]
        master.send_processdata()
        master.receive_processdata(10_000)
        master.state = pysoem.OP_STATE
        master.write_state()
        wkc = 0
        for _ in range(200):
            master.send_processdata()
            wkc = master.receive_processdata(10_000)
            if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        for _ in range(options.get("cycles", 20)):
            master.send_processdata()
            wkc = master.receive_processdata(10_000)
            time.sleep(0.001)
        result["op"] = master.read_state()
        result["wkc"] = wkc
        result["expected_wkc"] = master.expected_wkc
        result["al_op"] = [(s.state, s.al_status) for s in master.slaves]
        result["inputs"] = [bytes(s.input).hex() for s in master.slaves]
        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
