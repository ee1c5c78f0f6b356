"""The IgH-based formats of ``ecatcfg export`` (``cli/export.py``): ``igh-c`` (a C source
and its header), ``lcec`` (LinuxCNC's ``ethercat.xml``) and ``ros2`` (ethercat_driver_ros2's
ros2_control fragment and a generic-slave YAML per slave beside it), all from the IgH
configuration of the ENI (``eni/export/igh.py``); each output written atomically.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ecatcfg.eni.plan import NetworkPlan


def _c_outputs(args: argparse.Namespace, out: Path) -> Path:
    from ecatcfg.errors import UsageError
    header = out.with_suffix(".h")
    if header == out:
        raise UsageError(f"-o {args.output}: the C source needs another suffix than .h")
    return header


def _write(outputs: list[tuple[Path, bytes]]) -> None:
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import write_atomic
    for path, data in outputs:
        try:
            write_atomic(path, data)
        except OSError as exc:
            raise UsageError(f"{path}: cannot write: {exc.strerror}") from None


def write_igh_c(args: argparse.Namespace, plan: NetworkPlan, out: Path, digest: str) -> int:
    from ecatcfg import __version__
    from ecatcfg.eni.export import igh_c
    from ecatcfg.eni.export.igh import igh_config
    config = igh_config(plan, args.eni)
    header = _c_outputs(args, out)
    source, text = igh_c.render(config, header.name, Path(args.eni).name, digest,
                                __version__)
    _write([(out, source), (header, text)])
    print(f"wrote {out}, {header}: {len(config.slaves)} slaves, "
          f"{sum(len(s.sdos) for s in config.slaves)} SDO downloads, "
          f"{len(config.registrations)} variables", file=sys.stderr)
    return 0


def write_lcec(args: argparse.Namespace, plan: NetworkPlan, out: Path, digest: str) -> int:
    from ecatcfg import __version__
    from ecatcfg.eni.export import lcec
    from ecatcfg.eni.export.igh import igh_config
    config = igh_config(plan, args.eni)
    xml, extra = lcec.render(config, args.eni, Path(args.eni).name, digest, __version__,
                             out.stem)
    _write([(out, xml), *((out.with_name(name), data) for name, data in extra)])
    print(f"wrote {out}{f' and {len(extra)} initCmds files' if extra else ''}: "
          f"{len(config.slaves)} slaves, "
          f"{sum(len(s.sdos) for s in config.slaves)} SDO downloads", file=sys.stderr)
    return 0


def write_ros2(args: argparse.Namespace, plan: NetworkPlan, out: Path, digest: str) -> int:
    from ecatcfg import __version__
    from ecatcfg.eni.export import ros2
    from ecatcfg.eni.export.igh import igh_config
    config = igh_config(plan, args.eni)
    fragment, files = ros2.render(config, args.eni, out.stem, Path(args.eni).name, digest,
                                  __version__)
    _write([(out, fragment), *((out.with_name(name), data) for name, data in files)])
    print(f"wrote {out} and {len(files)} slave configurations beside it", file=sys.stderr)
    return 0


WRITERS: dict[str, Callable[[argparse.Namespace, NetworkPlan, Path, str], int]] = {
    "igh-c": write_igh_c, "lcec": write_lcec, "ros2": write_ros2}
