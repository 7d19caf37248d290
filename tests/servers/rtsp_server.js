// An RTSP server for the live aid's tests: rtsp-streaming-server (npm), with every TCP and UDP
// socket it opens bound to 127.0.0.1 (it binds to all interfaces itself).
// node rtsp_server.js MODULE_DIR PUBLISH_PORT CLIENT_PORT RTP_PORT_START
"use strict";
const net = require("net");
const dgram = require("dgram");

const listen = net.Server.prototype.listen;
net.Server.prototype.listen = function (port, ...rest) {
  if (typeof port === "number") {
    const callback = rest.find((item) => typeof item === "function");
    return listen.call(this, port, "127.0.0.1", callback);
  }
  return listen.call(this, port, ...rest);
};
const bind = dgram.Socket.prototype.bind;
dgram.Socket.prototype.bind = function (port, ...rest) {
  if (typeof port === "number" || port === undefined) {
    const callback = rest.find((item) => typeof item === "function");
    return bind.call(this, port || 0, "127.0.0.1", callback);
  }
  return bind.call(this, port, ...rest);
};

const RtspServer = require(process.argv[2]).default;
const [publishPort, clientPort, rtpPortStart] = process.argv.slice(3).map(Number);
const server = new RtspServer({ serverPort: publishPort, clientPort, rtpPortStart, rtpPortCount: 400 });
server.start().then(() => console.log("ready"), (error) => { console.error(error); process.exit(1); });
process.on("SIGTERM", () => process.exit(0));
