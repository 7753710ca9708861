"""On a host: its snapshot (one SSH command), the operations that compare
against it, apt and pinned apt repositories, what the host is (platform)."""
