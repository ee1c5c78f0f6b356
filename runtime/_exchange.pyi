# The compiled exchange of one cyclic frame (runtime/_exchange.c); optional at build time.
import socket

def exchange(sock: socket.socket,
             prepared: tuple[bytearray, bytes, bytes, bytes, bytearray, bytes, bytearray],
             reply: bytearray, idx: int, timeout: float) -> tuple[int, int]: ...
