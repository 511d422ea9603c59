// One plate everywhere: the studio's preview, which samples the atlases itself (so that paint
// shows at once), draws what `refocus export --what sharp` writes, output rules included.
#include <torch/torch.h>

#include <doctest/doctest.h>

#include <algorithm>

#include "edit/recompose.h"
#include "fit/fit_engine.h"
#include "io/image_file.h"
#include "io/tensor_image.h"
#include "metrics/metrics.h"
#include "project/project.h"
#include "render/preview.h"
#include "session/fit_session.h"
#include "test_util.h"

using namespace refocus;

TEST_CASE("the preview's sharp plate is the exported plate, picture for picture") {
    // Rack focus with a walker: the fallback, the sharper-view rule and the lock all act.
    test::TinyClip c = test::make_tiny("one_plate", "rack", "160x90");
    auto r = test::cli("fit '" + c.project.string() + "' --iters 60");
    INFO(r.output);
    REQUIRE(r.code == 0);
    const std::vector<Image> exported = test::export_sharp(c, "sharp");

    const Project project = Project::load(c.project);
    PrepareLog log;
    auto engine = open_fitted(project, log);
    Image bg_atlas, fg_atlas;
    {
        torch::NoGradGuard g;
        bg_atlas = tensor_to_image(engine->model().atlas_bg().contiguous());
        const torch::Tensor fg = engine->model().atlas_fg();
        if (fg.defined()) fg_atlas = tensor_to_image(fg.contiguous());
    }
    int with_rules = 0;
    double worst = 1e9, atlas_mean = 0;
    for (int t = 0; t < int(exported.size()); ++t) {
        const FrameMaps m = frame_maps(*engine, t);
        const bool two = !m.fg.empty();
        const PreviewLayers with =
            composite_layers(bg_atlas, m.uv_bg, two ? fg_atlas : Image(), m.uv_fg, m.alpha, 1,
                             m.bg_fix, two ? m.fg_fix : Image());
        const PreviewLayers without =
            composite_layers(bg_atlas, m.uv_bg, two ? fg_atlas : Image(), m.uv_fg, m.alpha, 1);
        const double same = psnr(with.composite, exported[t]);
        const double atlas_only = psnr(without.composite, exported[t]);
        INFO("frame " << t << ": preview with the rules " << same << " dB from the export, "
                      << "atlases alone " << atlas_only << " dB");
        CHECK(same > 45.0);
        with_rules += atlas_only < same - 3.0;
        worst = std::min(worst, same);
        atlas_mean += atlas_only / double(exported.size());
    }
    MESSAGE("preview against export: worst frame " << worst << " dB; the atlases alone (no fix) "
                                                   << atlas_mean << " dB on average");
    // The rules (and the engine's own sampling) acted: the atlases alone differ from the plate.
    CHECK(with_rules > 0);
}
