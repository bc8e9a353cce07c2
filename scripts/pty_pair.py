#!/usr/bin/env python3
"""A null-modem cable between two pseudo-terminals, for serial SITL tests.

Opens two pseudo-terminal pairs, puts both slave ends in raw mode, prints one line on stdout:

    ptys /dev/pts/A /dev/pts/B

and then copies every byte written on A to B and back, until stdin closes, SIGTERM or
SIGINT. One program opens A as its serial port (e.g. `amstack twin serve --mavlink
serial:/dev/pts/A:921600`), the other B (`amstack fly --link mavlink:serial:/dev/pts/B:921600`):
they talk as over a serial cable, with the kernel's tty layer on both sides. A pty has no
baud rate: the bytes move as fast as the programs write them.

At exit it prints the bytes copied each way on stderr: `copied A->B N, B->A M`.
Standard library only (socat does the same; this keeps the tests free of a system package).
"""

import os
import select
import signal
import sys
import tty


def main():
    ends = []
    for _ in range(2):
        master, slave = os.openpty()
        # Raw before anyone opens it: a cooked pty echoes, and the echo would loop through
        # the relay.
        tty.setraw(slave)
        ends.append((master, slave, os.ttyname(slave)))
    (ma, _sa, pa), (mb, _sb, pb) = ends
    print(f"ptys {pa} {pb}", flush=True)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    copied = {ma: 0, mb: 0}
    other = {ma: mb, mb: ma}
    watch = [ma, mb, sys.stdin.fileno()]
    while not stop:
        try:
            ready, _, _ = select.select(watch, [], [], 0.2)
        except InterruptedError:
            continue
        for fd in ready:
            if fd == sys.stdin.fileno():
                if not os.read(fd, 4096):
                    stop.append(1)
                continue
            try:
                data = os.read(fd, 65536)
            except OSError:
                # No slave open on this side yet (EIO): wait for one.
                continue
            view = memoryview(data)
            while view:
                n = os.write(other[fd], view)
                view = view[n:]
            copied[fd] += len(data)
    print(f"copied A->B {copied[ma]}, B->A {copied[mb]}", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
