"""rosbag2-layout MCAP bags: writing, reading, reindexing, replay."""
