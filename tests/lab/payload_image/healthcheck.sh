#!/bin/sh
# Healthy while the payload touched /tmp/heartbeat within the last 6 s.
beat=$(stat -c %Y /tmp/heartbeat 2>/dev/null) || { echo "no heartbeat yet"; exit 1; }
age=$(( $(date +%s) - beat ))
[ "$age" -le 6 ] || { echo "heartbeat is ${age}s old"; exit 1; }
echo "heartbeat ${age}s old"
