"""Defaults for the laptops group (override all.py)."""

# Laptops get the payload image and compose file for development, no autostart.
payload_autostart = False
# Laptops have a display for rviz; declare x11_user per laptop.
display = True
