# The compiled exchange of one cyclic frame (runtime/_exchange.c); optional at build time.
import socket

def exchange(sock: socket.socket, frame: bytearray, index_at: bytes, reply: bytearray,
             shape: bytes, idx: int, timeout: float) -> tuple[int, int]: ...
