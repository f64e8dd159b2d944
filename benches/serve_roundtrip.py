"""Round trips of `POST /api/render` over one keep-alive connection against the server's own part of each
(BENCHMARKS.md §8): a gap between the two would be a stall in the connection (Nagle against a delayed ACK), not
work.

The server is `lobe serve examples/brdfs --port 0`. The client sets TCP_NODELAY, as browsers do, and sends each
request's head and body in one write, then in two; 15 requests of each kind after one warm-up, VR^n at 512² on the
built-in paper sphere (n = 50, parameters live). The server part is its `X-Lobe-Render-Ms` header (render + PNG).

    python benches/serve_roundtrip.py [path/to/lobe]
"""
import json
import re
import socket
import statistics
import subprocess
import sys
import time


def main():
    binary = sys.argv[1] if len(sys.argv) > 1 else "target/release/lobe"
    server = subprocess.Popen([binary, "serve", "examples/brdfs", "--port", "0"], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    try:
        port = None
        for line in server.stdout:
            m = re.search(r"127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        if port is None:
            sys.exit("the server printed no address")
        conn = socket.create_connection(("127.0.0.1", port))
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        body = json.dumps({"name": "vr.brdf", "text": "VR^n", "params": {"n": 50}, "size": 512, "scene": ""}).encode()
        head = (f"POST /api/render HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Lobe-Client: 1\r\n"
                f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n").encode()

        def request(split):
            t = time.perf_counter()
            if split:
                conn.sendall(head)
                conn.sendall(body)
            else:
                conn.sendall(head + body)
            buf = b""
            while b"\r\n\r\n" not in buf:
                buf += conn.recv(65536)
            h, rest = buf.split(b"\r\n\r\n", 1)
            h = h.decode()
            n = int(re.search(r"(?i)content-length: (\d+)", h).group(1))
            while len(rest) < n:
                rest += conn.recv(65536)
            status = h.split()[1]
            if status != "200":
                sys.exit(f"the server answered {status}: {rest[:300]!r}")
            server_ms = float(re.search(r"(?i)x-lobe-render-ms: ([\d.]+)", h).group(1))
            return (time.perf_counter() - t) * 1e3, server_ms

        print("| writes per request | median round trip | median server part |")
        print("|---|---|---|")
        for split in (False, True):
            request(split)
            runs = [request(split) for _ in range(15)]
            rt = statistics.median(r for r, _ in runs)
            sv = statistics.median(s for _, s in runs)
            print(f"| {'two (head, body)' if split else 'one'} | {rt:.1f} ms | {sv:.1f} ms |")
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    main()
