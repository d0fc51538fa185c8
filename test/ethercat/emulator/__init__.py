"""Software EtherCAT slave emulator for the tests (see ``test/ethercat/README.md``).

Modules: :mod:`.frames` (frame layout), :mod:`.sii` (SII image), :mod:`.esc` (ESC
registers, AL state machine, SM/FMMU, watchdog), :mod:`.cia402` (drive),
:mod:`.analog` (analog input terminal), :mod:`.physics` (plant simulators and
scalings), :mod:`.bus` (chain, WKC, fault injection), :mod:`.config` (configuration),
:mod:`.server` (process main loop and side channel), :mod:`.client` (side-channel
client).
"""
