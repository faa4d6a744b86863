"""What a run writes and reads back: checkpoint files (``checkpoint``), what they hold (``saved``), the run
folder (``folder``), warm starts (``warm_start``), the metrics log (``logger``), learning-curve plots
(``plots``) and the exported ONNX graph (``onnx_policy``)."""
