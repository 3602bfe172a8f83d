"""The spec language every command's TOML file is written in (sweep, tune and compare specs, ``--gains``
files): the schema tables are read with (:mod:`.schema`), one setting's value and sampling ranges
(:mod:`.settings`), the scenario tables with their variants and scales (:mod:`.scenario`), and the user
code a spec names (:mod:`.plugins`). docs/sweep.md, docs/tune.md and docs/compare.md describe the files.
Imports nothing here, so that the command line's plugin loading stays light."""
