"""EtherCAT test infrastructure: a software EtherCAT slave emulator that answers SOEM
(pysoem 1.1.13) on a veth pair, and the harness that creates the veth pair / network
namespace and runs the emulator in its own process.  See README.md in this directory."""
