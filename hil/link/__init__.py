"""The host's links to the outside: the board client (:mod:`.board`), the transports it speaks over
(:mod:`.transports`: serial, pty, pyserial URLs, CAN, and those other packages register) and the phone's
live sample streams (:mod:`.sources`)."""
