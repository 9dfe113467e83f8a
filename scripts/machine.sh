#!/usr/bin/env bash
# Prints the machine a benchmark ran on.
cpu=$(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | cut -d: -f2- | sed 's/^ *//')
echo "machine: ${cpu:-unknown cpu}, $(nproc) logical cores, $(free -g 2>/dev/null | awk '/Mem:/{print $2" GiB"}'), $(uname -sm), $(date -u +%Y-%m-%d)"
