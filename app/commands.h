#pragma once
// One function per subcommand; each returns the process exit code and throws refocus::Error
// (or std::runtime_error) with a one-line message on failure.
namespace refocus {
int cmd_new(int argc, char** argv);
int cmd_info(int argc, char** argv);
int cmd_bench(int argc, char** argv);  // refocus bench <what> (app/cmd_bench.cpp)
int cmd_synth(int argc, char** argv);
}  // namespace refocus
