// refocus atlas: bring a repainted atlas back into a project headless (paper Fig. 1: edit the
// atlas in Photoshop, the edit follows every frame), or clear a layer's edits.
#include <cstdio>

#include "args.h"
#include "commands.h"
#include "edit/atlas_edit.h"
#include "session/fit_session.h"
#include "io/tensor_image.h"
#include "util/error.h"
#include "util/lock.h"

namespace refocus {

int cmd_atlas(int argc, char** argv) {
    Args a(argc, argv, 2, {"clear"});
    a.check_known({"import", "clear", "layer"});
    const char* usage =
        "usage: refocus atlas <project> --import <file> --layer bg|fg | --clear [--layer bg|fg]";
    if (a.positional().size() != 1 || a.has("import") == a.has("clear")) throw Error(usage);
    const std::string layer = a.get("layer", a.has("clear") ? "all" : "");
    if (layer != "bg" && layer != "fg" && !(layer == "all" && a.has("clear")))
        throw Error(layer.empty() ? "--import needs --layer bg|fg" : "--layer must be bg or fg");
    Project project = Project::load(a.positional()[0]);
    const auto lock = ProjectLock::acquire(project.dir, "refocus atlas");
    ProjectEdits edits = ProjectEdits::load(project);

    if (a.has("clear")) {
        for (int i = 0; i < 2; ++i)
            if (layer == "all" || layer == (i ? "fg" : "bg")) edits.layer(i).clear();
        edits.save(project);
        std::printf("atlas edits cleared (%s)\n", layer.c_str());
        return 0;
    }
    PrepareLog log;
    auto engine = open_fitted(project, log);
    {
        std::lock_guard<std::mutex> lock(engine->model_mutex());
        torch::NoGradGuard g;
        if (!engine->has_atlas())
            throw Error("the perframe preset has no atlas to edit (refit with --preset fast)");
        torch::Tensor base =
            layer == "bg" ? engine->model().atlas_bg() : engine->model().atlas_fg();
        if (!base.defined())
            throw Error("the fit has one layer: no foreground atlas (use --layer bg)");
        edits.layer(layer == "fg").set_base(tensor_to_image(base.contiguous()));
    }
    AtlasEditor& ed = edits.layer(layer == "fg");
    const int64_t n = ed.import_image(a.get("import"));
    edits.save(project);
    std::printf("atlas %s: %lld of %d px edited from %s; saved %s\n", layer.c_str(),
                static_cast<long long>(n), ed.width() * ed.height(), a.get("import").c_str(),
                ProjectEdits::file_of(project, layer == "fg").string().c_str());
    return 0;
}

}  // namespace refocus
