"""Fleet screening: the graphs' node logic over thousands of recordings, offline, on Ray.

``fleet`` (:mod:`.cli`) takes recordings (bag directories, a directory of them, globs, URIs or a
manifest with each vehicle's graph, parameters and stored calibration: :mod:`.manifest`), runs
one task per recording (:mod:`.job`: the offline engine with the vehicle's parameters, outputs
summarised as they stream: :mod:`.summaries`), writes Parquet datasets partitioned by vehicle
and date, and a report ranking the vehicles by concern (:mod:`.report`). :mod:`.synthetic`
writes a fleet with planted faults to prove it.

What is Ray's and what is ours, and why:

* **Scheduling, workers, the cluster: Ray** (``ray.remote`` tasks, ``ray.wait``, ``ray.init``
  embedded or ``address=`` of a cluster). One task per recording, one CPU each. A vehicle's
  calibration chain is a chain of task dependencies: the next drive's task takes the previous
  task's calibration ObjectRef as an argument, so Ray's scheduler orders a vehicle's drives
  and runs different vehicles in parallel; nothing of ours waits or polls.
* **Reading a recording: ours (rosbags through ``bag_io``), not ``ray.data.read_mcap``.**
  ``read_mcap`` turns MCAP files into a Dataset of rows (one per message) split into blocks
  that are processed independently and in no guaranteed order. The estimators are stateful
  filters that must see one recording's messages in log-time order, in one process, each
  decoded into the contract's message type; rows of a Dataset would cost a conversion per
  message and lose the order. The engine streams a bag chunk by chunk (memory per task stays
  bounded) and also reads rosbag2 ``.mcap.zstd`` bags ``read_mcap`` cannot open.
* **Remote files: pyarrow.fs** (what Ray itself reads through): a recording given as a URI is
  copied to the worker's scratch space first, since rosbags reads local files.
* **Results: pyarrow** Parquet files written by the driver as each task completes, atomically
  and in hive partitions; a rerun skips what exists. Ray Data's ``write_parquet`` writes a
  whole Dataset at the end, with no per-recording atomicity to resume from.
* **Report: pandas + matplotlib** over the (small) result tables.
"""
