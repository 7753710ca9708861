#!/bin/sh
# Heartbeat loop: one line every 2 s and a fresh /tmp/heartbeat for the health check.
# A broken build keeps logging but never heartbeats, so its health check fails.
trap 'echo "payload $PAYLOAD_VERSION: stopping"; exit 0' TERM INT
echo "payload $PAYLOAD_VERSION: starting"
while :; do
    if [ -n "$PAYLOAD_BROKEN" ]; then
        echo "payload $PAYLOAD_VERSION: broken build, no heartbeat $(date -u +%H:%M:%S)"
    else
        touch /tmp/heartbeat
        echo "payload $PAYLOAD_VERSION: heartbeat $(date -u +%H:%M:%S)"
    fi
    sleep 2 &
    wait $!
done
