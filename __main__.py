from ecatcfg.cli import console

console()
