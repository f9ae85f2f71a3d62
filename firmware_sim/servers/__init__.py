"""The board served to a host: on a pseudo-terminal (:mod:`.pty_server`), on a CAN bus (:mod:`.can_server`),
and as the built-in emulator's transports (:mod:`.transports`: ``emu://`` in process, ``spawn://`` a
``firmware-sim`` child), which ``pyproject.toml`` registers as ``vscmg_hil.transports`` entry points."""
