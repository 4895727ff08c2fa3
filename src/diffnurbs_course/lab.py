"""JupyterLab server settings for the course: widgets that answer a drag at once."""

from jupyter_server.services.kernels.connection.channels import ZMQChannelsWebsocketConnection


class NoDelayConnection(ZMQChannelsWebsocketConnection):
    """The kernel's websocket with Nagle's algorithm off.

    Jupyter Server leaves it on: each small message a kernel sends (busy, a widget's
    update, idle) then waits for the browser to acknowledge the one before, which it delays
    by up to 40 ms. Dragging a point through a widget makes one such exchange per move.
    """

    def connect(self):
        self.websocket_handler.set_nodelay(True)
        return super().connect()
