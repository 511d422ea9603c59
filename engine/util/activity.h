#pragma once
// What the process is doing now, for progress lines while a long stage prints nothing else: the
// CLI's StageProgress repeats its line with it every 10 s (app/progress.h), so a user never
// watches a silent process. Set by the model's set-up and read from another thread.
#include <string>

namespace refocus {

void set_activity(const std::string& what);  // "" when done
std::string current_activity();

}  // namespace refocus
