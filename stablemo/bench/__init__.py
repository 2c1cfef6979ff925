"""Every benchmark, on public names only: AITS (the paper's Table 5), training speed, streaming, foot-skate cleanup. The commands are `stablemo bench ...` (stablemo.cli.bench)."""
