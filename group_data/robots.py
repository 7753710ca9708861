"""Defaults for the robots group (override all.py)."""

# Robots run the payload at boot.
payload_autostart = True
# Static vendor rules from files/udev/ installed on every robot.
udev_vendor_rules = ["60-usb-serial-low-latency.rules"]
