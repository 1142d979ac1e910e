//! Server flows (modbus_receive, modbus_reply): owned by the server work (issue 3).
