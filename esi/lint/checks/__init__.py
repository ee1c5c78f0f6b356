"""The semantic lint rules, one module per topic; importing this package registers them.

    values    ESI0xx  the file as a whole: parsing, numbers, identities, names
    pdo       ESI1xx  PDOs and their entries against the dictionary and SyncManagers
    sm        ESI2xx  SyncManagers, FMMUs and the mailbox
    soe       ESI216-217  the SoE InitCmds (mailbox group)
    coe       ESI3xx  the CoE object dictionary and InitCmds
    dc        ESI4xx  distributed-clock op modes
    eeprom    ESI5xx  the EEPROM (SII) description
    modules   ESI6xx  modular devices: slots, modules, module libraries
"""

from ecatcfg.esi.lint.checks import (coe, dc, eeprom, modules, pdo, sm, soe,  # noqa: F401
                                     values)
