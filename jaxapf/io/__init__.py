"""What the tools share about the files around a run: one writer per output and atomic writes
(:mod:`.lock`), never through a name planted in the folder (:mod:`.names`), and the versions recorded with
every result (:mod:`.versions`). Imports nothing heavy, so that the command line's help and errors stay
fast."""
