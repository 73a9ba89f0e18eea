"""Live adapters: CAN (python-can + cantools) and serial (pyserial), each a sample Source."""
