// Observation-only rawlog (odometry, scan, odometry, scan...) -> actions/sensory-frames rawlog,
// which MRPT's rbpf-slam needs (it crashes on the other format). Each scan gets the odometry
// increment since the previous scan as a CActionRobotMovement2D under MRPT's Gaussian motion
// model, whose ratios come from the command line. Only scans after at least min_m of travel or
// min_rad of turn since the last kept one are kept (keyframes; the filter is told to process
// every frame it gets), and their indices are printed one a line. Built and run by
// bench/mrpt_logs.py.
//
//   mrpt_to_sf IN.rawlog OUT.rawlog a1 a2 a3 a4 min_std_xy min_std_phi min_m min_rad
#include <mrpt/io/CFileGZInputStream.h>
#include <mrpt/io/CFileGZOutputStream.h>
#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/obs/CObservationOdometry.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/serialization/CArchive.h>

#include <cstdio>
#include <cmath>
#include <cstdlib>

using namespace mrpt::obs;

int main(int argc, char** argv)
{
	if (argc != 11)
	{
		std::fprintf(
			stderr, "usage: %s IN OUT a1 a2 a3 a4 min_std_xy min_std_phi min_m min_rad\n",
			argv[0]);
		return 2;
	}
	mrpt::io::CFileGZInputStream in(argv[1]);
	mrpt::io::CFileGZOutputStream out(argv[2]);
	auto ar_in = mrpt::serialization::archiveFrom(in);
	auto ar_out = mrpt::serialization::archiveFrom(out);
	CActionRobotMovement2D::TMotionModelOptions model;
	model.modelSelection = CActionRobotMovement2D::mmGaussian;
	model.gaussianModel.a1 = std::atof(argv[3]);
	model.gaussianModel.a2 = std::atof(argv[4]);
	model.gaussianModel.a3 = std::atof(argv[5]);
	model.gaussianModel.a4 = std::atof(argv[6]);
	model.gaussianModel.minStdXY = std::atof(argv[7]);
	model.gaussianModel.minStdPHI = std::atof(argv[8]);
	const double min_m = std::atof(argv[9]), min_rad = std::atof(argv[10]);
	bool seen = false, first = true;
	mrpt::poses::CPose2D kept, now;
	mrpt::Clock::time_point stamp;
	size_t scans = 0;
	while (true)
	{
		mrpt::serialization::CSerializable::Ptr obj;
		try
		{
			obj = ar_in.ReadObject();
		}
		catch (const std::exception&)
		{
			break;  // end of file
		}
		if (auto odo = std::dynamic_pointer_cast<CObservationOdometry>(obj))
		{
			now = odo->odometry;
			if (!seen) kept = now;
			stamp = odo->timestamp;
			seen = true;
		}
		else if (auto scan = std::dynamic_pointer_cast<CObservation2DRangeScan>(obj))
		{
			const mrpt::poses::CPose2D increment = now - kept;
			const bool keep = first || increment.norm() >= min_m ||
				std::abs(increment.phi()) >= min_rad;
			++scans;
			if (!keep) continue;
			first = false;
			kept = now;
			CActionCollection actions;
			CActionRobotMovement2D move;
			move.computeFromOdometry(increment, model);
			move.timestamp = stamp;
			actions.insert(move);
			CSensoryFrame frame;
			frame.insert(scan);
			ar_out << actions << frame;
			std::printf("%zu\n", scans - 1);
		}
	}
	return 0;
}
