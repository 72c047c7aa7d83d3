"""The live view in Foxglove: the camera with the mask and target, the histogram, the command,
SegCorridor's rows and the path, streamed by `segmin replay --live`, `segmin nav-eval --live` and
the node's `live_port` over foxglove-sdk's WebSocket server, in the topics and schemas of the bags
nav-eval writes (`view` builds the messages, `server` serves them, `publisher` streams a replay's
or the node's steps, `options` holds the command-line flags). Needs the [live] extra."""
