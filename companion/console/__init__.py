"""The pilot console: a local web page to see the camera, fly with a gamepad, intervene and
watch the policy learn. ``col console`` serves it (aiohttp: static HTML/JS and one WebSocket);
the page's sticks are a human input like a ground station's MANUAL_CONTROL."""
