"""The board's one owner: the thread that holds the arm's core and alone writes to the board,
its inbox's lanes, and the local lane by which clients on this machine reach it.

- `loop`: `Owner`, the owner's thread: inputs in (stops first), the core stepped, its
  effects carried out (bytes to the board, outcomes and news to the clients).
- `conns`: the lane's sockets, for the owner's thread: its clients' connections
  accepted, read, written, leased and dropped.
- `desk`: what the lane's clients ask, read into the owner's inbox, and the answers
  routed back to them.
- `news`: what the owner tells of what its core did, to its listeners and to the lane's
  watchers, and what it keeps for a client not there yet (a recorder, a ROS bridge).
- `teller`: the thread that tells in-process futures, listeners and the log, so that the
  owner's thread never runs anyone else's code; and the state told, with its waits.
- `lane`: the local lane's protocol (a Unix socket, one JSON object a line); `where`:
  where each server's socket is.
- `client`: `Remote`, a client of the owner over the lane: the ROS bridges, the command
  line, the web view and the Python client reach a local server through it.
- `quick`: `al5d send stop` without its imports: the stop by the lane, from a bare
  interpreter.

This layer imports `al5d.arm`, `al5d.ssc32u` (never its emulator) and `al5d.clock`;
nothing here knows ROS.
"""
