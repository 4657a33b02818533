# The Foxglove WebSocket protocol server (foxglove.sdk.v1 / foxglove.websocket.v1), :8765.
