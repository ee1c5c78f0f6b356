"""pysoem with a module of ``ecatcfg export --format pysoem``, reading and writing process
data by variable name, in its own process inside the test's network namespace, driven
step by step by the test: ``python export_io_probe.py IFACE MODULE.py``.

The user's sequence from the module's docstring (config_init, the module's ``setup``, its
``config_map``), then SAFEOP and OP.  It prints one JSON line after the mapping
(``mapped``): each slave's FMMU registers as SOEM programmed them (16 bytes each, hex,
read back with pysoem's register read, the reference for where SOEM put the slave's bits),
``sizes`` (len of slave.output, slave.input) and ``iomap``; or ``error`` (the module's
exception) and stops.  Then one line ``{"op": state}``, and after that one JSON reply per
JSON command read from stdin:

- ``{"read": [NAME, ...]}``: a few cycles, then ``values``: each variable read through
  the module's ``VARIABLES`` from pysoem's ``slave.input``/``slave.output`` bytes (null when
  the table's byte is outside them), ``module``: the module's ``read(master, NAME)`` (or
  the text of its exception), ``raw``: every slave's input bytes (hex), and ``settled``:
  whether the working counter and inputs came back steady before (:func:`settle`);
- ``{"write": {NAME: VALUE}}``: each written through ``VARIABLES`` into ``slave.output``
  (read-modify-write of the bytes pysoem gives), then cycles until steady (``settled``);
- ``{"stop": true}`` (or the end of stdin): INIT, close.

Between commands the process data cycle goes on (every 5 ms and the reply's time).
"""

from __future__ import annotations

import faulthandler
import importlib.util
import json
import queue
import signal
import sys
import threading
import time

import pysoem
from soem_patience import be_patient

STATE_TIMEOUT_US = 10_000_000      # a loaded 2-core machine: margin over the ~0.1 s needed
CYCLES = 10
SETTLE_CYCLES = 200
REPLY_US = 100_000
IDLE_S = 0.005                     # between cycles while no command waits: well inside the
                                   # SyncManager watchdogs of the corpus (100 ms)


def say(obj: dict) -> None:
    print(json.dumps(obj), flush=True)


def cycles(master: pysoem.Master, n: int = CYCLES) -> None:
    """``n`` cycles, each waiting for its frame up to REPLY_US: a shorter wait on a loaded
    machine sends frames faster than the emulated line answers them, and the backlog
    grows until nothing answers in time."""
    for _ in range(n):
        master.send_processdata()
        master.receive_processdata(REPLY_US)


def settle(master: pysoem.Master) -> bool:
    """Cycles until three in a row bring the same working counter (not 0) and the same
    inputs: the emulated line is a Python process on a loaded machine, a reply can come
    after SOEM stopped waiting for it, and the data set before must have gone round."""
    last, same = None, 0
    for _ in range(SETTLE_CYCLES):
        master.send_processdata()
        wkc = master.receive_processdata(REPLY_US)
        now = (wkc, [bytes(s.input) for s in master.slaves])
        same = same + 1 if wkc > 0 and now == last else 0
        if same >= 3:
            return True
        last = now
    return False


def window(master: pysoem.Master, entry) -> bytes:
    slave = master.slaves[entry.slave]
    return bytes(slave.input if entry.direction == "input" else slave.output)


def table_read(master: pysoem.Master, entry) -> int | None:
    """The variable's bits from the bytes pysoem gives for its slave, where the table says."""
    data = int.from_bytes(window(master, entry), "little")
    first = entry.byte * 8 + entry.bit
    if first + entry.bit_size > len(window(master, entry)) * 8:
        return None
    return data >> first & ((1 << entry.bit_size) - 1)


def table_write(master: pysoem.Master, entry, value: int) -> bool:
    old = window(master, entry)
    first = entry.byte * 8 + entry.bit
    if first + entry.bit_size > len(old) * 8:
        return False
    mask = ((1 << entry.bit_size) - 1) << first
    data = int.from_bytes(old, "little") & ~mask | (value << first) & mask
    master.slaves[entry.slave].output = data.to_bytes(len(old), "little")
    return True


def register(slave, address: int, size: int) -> bytes | None:
    """A register read with room for a slow emulated line (pysoem waits 2 ms by default),
    tried three times; None when it never answers."""
    for _ in range(3):
        try:
            return bytes(slave._fprd(address, size, REPLY_US))
        except pysoem.WkcError:
            continue
    return None


def fmmus(slave) -> list[str]:
    """The slave's FMMU registers (0x0600 + 16 n, as many as register 0x0004 says it has;
    one that never answers is given as an empty string)."""
    count = register(slave, 0x0004, 1)
    return [(register(slave, 0x0600 + 16 * k, 16) or b"").hex()
            for k in range(min(count[0] if count else 16, 16))]


def main() -> None:
    faulthandler.register(signal.SIGUSR1)     # where it waits, when the test gives up
    iface, module_path = sys.argv[1], sys.argv[2]
    spec = importlib.util.spec_from_file_location("exported", module_path)
    assert spec is not None and spec.loader is not None
    exported = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(exported)
    be_patient(pysoem)
    master = pysoem.Master()
    master.open(iface)
    try:
        found = master.config_init()
        try:
            exported.setup(master)
            iomap = exported.config_map(master)
        except Exception as exc:         # the module's own errors, reported as they are
            say({"found": found, "error": f"{type(exc).__name__}: {exc}"})
            return
        say({"found": found, "iomap": iomap,
             "sizes": [(len(s.output), len(s.input)) for s in master.slaves],
             "fmmus": [fmmus(s) for s in master.slaves]})
        master.state = pysoem.SAFEOP_STATE
        master.write_state()
        master.state_check(pysoem.SAFEOP_STATE, STATE_TIMEOUT_US)
        cycles(master, 1)
        master.state = pysoem.OP_STATE
        master.write_state()
        for _ in range(400):
            cycles(master, 1)
            if master.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE:
                break
        state = 0
        for _ in range(3):                # a read the loaded line answers late gives 0
            state = master.read_state()
            if state:
                break
        say({"op": state})
        # Commands through a thread; between them the cycle goes on, as an application's
        # would (a pause longer than the SyncManager watchdog takes the slaves out of OP).
        commands: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: [commands.put(x) for x in sys.stdin] and None
                         or commands.put(""), daemon=True).start()
        while True:
            try:
                line = commands.get_nowait()
            except queue.Empty:
                cycles(master, 1)
                time.sleep(IDLE_S)
                continue
            command = json.loads(line) if line else {"stop": True}
            if command.get("stop"):
                break
            if "write" in command:
                done = {name: table_write(master, exported.VARIABLES[name], value)
                        for name, value in command["write"].items()}
                say({"written": done, "settled": settle(master)})
                continue
            settled = settle(master)
            values, module = {}, {}
            for name in command["read"]:
                values[name] = table_read(master, exported.VARIABLES[name])
                try:
                    module[name] = exported.read(master, name)
                except Exception as exc:
                    module[name] = f"{type(exc).__name__}: {exc}"
            say({"values": values, "module": module, "settled": settled,
                 "raw": [bytes(s.input).hex() for s in master.slaves]})
        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()


if __name__ == "__main__":
    main()
