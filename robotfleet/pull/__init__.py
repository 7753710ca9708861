"""Pull mode: robots that fetch signed releases and converge themselves
(docs/pull.md)."""
