#pragma once
// One function per subcommand; each returns the process exit code and throws refocus::Error
// (or std::runtime_error) with a one-line message on failure.
namespace refocus {
int cmd_new(int argc, char** argv);
int cmd_info(int argc, char** argv);
int cmd_bench(int argc, char** argv);  // refocus bench <what> (app/cmd_bench.cpp)
int cmd_fit(int argc, char** argv);
int cmd_export(int argc, char** argv);
int cmd_atlas(int argc, char** argv);  // app/cmd_atlas.cpp
int cmd_synth(int argc, char** argv);
int cmd_batch(int argc, char** argv);     // refocus batch plan|run|status (app/cmd_batch.cpp)
int bench_fit(int argc, char** argv);     // refocus bench fit (app/bench_fit.cpp)
int bench_kernel(int argc, char** argv);  // refocus bench kernel (app/bench_kernel.cpp)
int bench_bound(int argc, char** argv);   // refocus bench bound (app/bench_bound.cpp)
int bench_motion(int argc, char** argv);  // refocus bench motion (app/bench_motion.cpp)
int bench_scale(int argc, char** argv);   // refocus bench scale (app/bench_scale.cpp)
int bench_corpus(int argc, char** argv);  // refocus bench corpus (app/bench/bench_corpus.cpp)
}  // namespace refocus
