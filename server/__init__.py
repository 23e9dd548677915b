"""The ship's web server: REST, WebSocket, thumbnails, control. Built by `server.app.create_app`."""
