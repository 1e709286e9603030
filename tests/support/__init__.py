"""What the tests share: reference models the fast implementations are checked against
(:mod:`.reference`), scripted boards (:mod:`.fakeboard`), waiting on a condition with a
deadline (:mod:`.waiting`), and harnesses for the emulator, the CLI and served boards."""
