"""The lab registry under the name the robots know it by, on this machine.

The robots reach the lab registry as ``<prefix>-services:5000`` on the lab
network; this machine reaches it on 127.0.0.1:<port> and cannot resolve
that name.  A fleet file written as a user writes it names the image
without its digest (``<prefix>-services:5000/ros/driver:1.1``), and publish
reads the digest from the registry by that name: an operator's machine must
resolve it as the robots do.  This forward proxy on 127.0.0.1 does that for
one process (its ``http_proxy``): a request for the robots' name goes to the
registry's local port; any other is refused (502), so nothing leaves the
machine.
"""

from __future__ import annotations

import http.server
import threading
import urllib.error
import urllib.parse
import urllib.request

FORWARDED = (
    "Content-Type",
    "Content-Length",
    "Docker-Content-Digest",
    "Docker-Distribution-Api-Version",
    "WWW-Authenticate",
    "Location",
)


class RegistryProxy:
    """``http://127.0.0.1:<port>`` as an HTTP proxy sending requests for
    ``name`` (host:port) to ``local`` (127.0.0.1:<port>)."""

    def __init__(self, name: str, local: str):
        proxy = self
        self.name, self.local = name, local
        self.requests: list[str] = []
        direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                self._forward(head=False)

            def do_HEAD(self):
                self._forward(head=True)

            def _forward(self, head: bool):
                parts = urllib.parse.urlsplit(self.path)
                proxy.requests.append(f"{self.command} {self.path}")
                if parts.scheme != "http" or parts.netloc != proxy.name:
                    self.send_error(502, f"only {proxy.name} is proxied")
                    return
                headers = {k: v for k, v in self.headers.items() if k.lower() in ("accept", "authorization")}
                request = urllib.request.Request(
                    f"http://{proxy.local}{parts.path}" + (f"?{parts.query}" if parts.query else ""),
                    method=self.command,
                    headers=headers,
                )
                try:
                    answer = direct.open(request, timeout=60)
                except urllib.error.HTTPError as error:
                    answer = error
                with answer:
                    body = b"" if head else answer.read()
                    self.send_response(answer.status if hasattr(answer, "status") else answer.code)
                    for name in FORWARDED:
                        if answer.headers.get(name) is not None:
                            self.send_header(name, answer.headers[name])
                    self.end_headers()
                    self.wfile.write(body)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def env(self) -> dict[str, str]:
        """The environment a process reads the registry through this proxy with."""
        return {
            "http_proxy": self.url,
            "HTTP_PROXY": self.url,
            "no_proxy": "127.0.0.1,localhost",
            "NO_PROXY": "127.0.0.1,localhost",
        }

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
