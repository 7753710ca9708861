"""What a pull robot and the operator's machine both read and write: the
formats of the protocol between them (release record, reports, waves, the
agent's files and configuration, a robot's data).  Imports neither side."""
