"""One router per concern; `server.app` includes them."""
