"""The operator's terminal: text out, typed lines in (no rclpy).

Either the process's own stdin/stdout, or a terminal device opened by path (`/dev/tty`,
the controlling terminal of whoever started the graph, or a pty's slave). A reader thread
turns what is typed into lines on a queue, so a node can wait for an answer with a
timeout while it also watches for a cancel. The end of input (the terminal closed,
stdin at EOF) is remembered and raised as TerminalClosed by every later read.
"""

import os
import queue
import sys
import threading


class TerminalClosed(RuntimeError):
    """No more input: the operator's terminal was closed."""


class OperatorTerminal:
    """`path` '' = stdin/stdout; else a terminal device opened read-write (never made the
    process's controlling terminal). Raises OSError when it cannot be opened. It stays open
    for the life of the process: its reader thread may be blocked in a read."""

    def __init__(self, path=''):
        self.path = path
        if path:
            fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
            self._reader = os.fdopen(fd, 'r', encoding='utf-8', errors='replace')
            self._writer = os.fdopen(os.dup(fd), 'w', encoding='utf-8', errors='replace')
            self.name = path
        else:
            self._reader, self._writer = sys.stdin, sys.stdout
            self.name = 'stdin'
        self._lines = queue.SimpleQueue()
        self._closed = None
        self._write_lock = threading.Lock()
        threading.Thread(target=self._read_lines, name='operator-terminal',
                         daemon=True).start()

    def _read_lines(self):
        try:
            for line in self._reader:
                self._lines.put(line.rstrip('\r\n'))
            why = f'end of input on {self.name}'
        except (OSError, ValueError) as error:   # the device went away, or was closed
            why = f'{self.name} could not be read: {error}'
        self._lines.put(TerminalClosed(why))

    def show(self, text):
        """Write `text` as it is (no newline added) and flush; False if it cannot."""
        with self._write_lock:
            try:
                self._writer.write(text)
                self._writer.flush()
                return True
            except (OSError, ValueError):
                return False

    def next_line(self, timeout_s):
        """The next typed line, or None when nothing is typed within `timeout_s`; raises
        TerminalClosed once the input has ended."""
        if self._closed is not None:
            raise self._closed
        try:
            item = self._lines.get(timeout=max(timeout_s, 0.0))
        except queue.Empty:
            return None
        if isinstance(item, TerminalClosed):
            self._closed = item
            raise item
        return item

    def drain(self):
        """Forget the lines typed so far (they answer no question asked now); returns how
        many."""
        count = 0
        while True:
            try:
                line = self.next_line(0.0)
            except TerminalClosed:
                return count
            if line is None:
                return count
            count += 1


__all__ = ['OperatorTerminal', 'TerminalClosed']
