"""Helpers shared by the tests (one copy each): subprocess runs of the CLI, network and
Zenoh peers, bench emulators and a scripted serial port."""
