"""What other roles may read of the x11 role (through these functions, never
its settings themselves)."""


def has_display(data) -> bool:
    """The host has a display for GUI containers: a GPU payload there gets
    the graphics part of the driver too (the gpu role)."""
    return bool(data.get("x11_enabled"))
